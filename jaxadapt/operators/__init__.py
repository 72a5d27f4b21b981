"""Tone-reproduction operators, one module per published model.

Each exposes ``Params``, ``State``, ``init``, ``step`` and ``run`` (see the
README's architecture section).
"""
