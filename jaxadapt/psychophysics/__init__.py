"""Psychophysics: experiment designs, psychometric fits and group statistics.

``design`` holds the method of constant stimuli and the 2015 paper's two
protocols as data, ``fit`` the cumulative-Gaussian fits, ``stats`` the group
test between conditions, and ``trials`` reads trial tables and writes fit
tables (the command line's ``psychometric`` subcommand).
"""
