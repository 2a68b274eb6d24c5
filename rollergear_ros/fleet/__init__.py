"""Fleets of drive logs on Dask: the runs, their report, and simulated fleets."""

from ..base.face import lazy_face

#: the wing's API (the names other wings use) and the module that defines each
_FACE = {
    "drift": "report",
    "write_fleet_report": "report",
    "FleetRun": "run",
    "SLICE_MESSAGES": "logs",
    "dask_client": "cluster",
    "discover": "logs",
    "run_calibrate": "run",
    "run_replay": "run",
    "DAY_NS": "simulated",
    "FleetScenario": "simulated",
    "simulate_fleet": "simulated",
}

__all__, __getattr__, __dir__ = lazy_face(__name__, _FACE)
