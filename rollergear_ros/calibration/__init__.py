"""Closing the loop: samples, block means and candidate columns, forward selection,
``calibrate`` and its parameter file, the report, the rig simulator and the paper's figures.
"""

from ..base.face import lazy_face

#: the wing's API (the names other wings use) and the module that defines each
_FACE = {
    "CalibrationSettings": "calibrate",
    "calibrated_yaml": "written",
    "write_figures": "figures",
    "REPORT_FILES": "report",
    "reading_choice": "report",
    "write_report": "report",
    "load_samples": "samples",
    "power_balance_warning": "samples",
    "table_samples": "samples",
    "TimeSpan": "samples",
    "DeclaredEffect": "simulate",
    "PROFILES": "simulate",
    "SimulationOptions": "simulate",
    "write_rig_bag": "simulate",
    "write_simulation": "simulate",
    "IDLE_PRIORITY_S": "traceworker",
    "TraceBuffer": "tracing",
    "TraceRequest": "tracing",
    "TraceResult": "tracing",
    "TraceWorker": "traceworker",
}

__all__, __getattr__, __dir__ = lazy_face(__name__, _FACE)
