"""Fleets of drive logs on Dask: the runs, their report, and simulated fleets."""
