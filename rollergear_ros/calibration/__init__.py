"""Closing the loop: samples, block means and candidate columns, forward selection,
``calibrate`` and its parameter file, the report, the rig simulator and the paper's figures.
"""
