"""Psychophysics: experiment designs, psychometric fits, group statistics and
simulated observers.

``design`` holds the method of constant stimuli and the 2015 paper's two
protocols as data, ``fit`` the cumulative-Gaussian fits, ``stats`` the group
test between conditions, ``trials`` reads trial tables and writes fit
tables (the command line's ``psychometric`` subcommand), and ``observer``
renders the paper's stimuli with the 2015 operator and simulates model
observers who judge them (``psychometric simulate``).
"""
