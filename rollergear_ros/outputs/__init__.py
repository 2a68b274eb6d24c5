"""What the estimates become besides the output topics: the stamped estimate's codec, the live
loss map, the VECTO loss map, rerun recordings, and the exported tables.
"""

from ..base.face import lazy_face

#: the wing's API (the names other wings use) and the module that defines each
_FACE = {
    "EXPORT_KINDS": "exports",
    "Export": "exports",
    "build_fmu": "fmu",
    "coefficients_moved": "livemap",
    "live_map": "livemap",
    "oil_moved": "livemap",
    "to_multiarray": "livemap",
    "build_map": "lossmap",
    "coverage_warning": "lossmap",
    "grid": "lossmap",
    "map_comments": "lossmap",
    "plot_map": "lossmap",
    "reverse_path": "lossmap",
    "vtlm_problems": "lossmap",
    "write_vtlm": "lossmap",
    "MIN_SAMPLES": "measuredmap",
    "measured_cells": "measuredmap",
    "write_measured_map": "measuredmap",
    "MAX_MAP_TEMPERATURES": "oiltable",
    "oil_dependence_warning": "oiltable",
    "write_long_table": "oiltable",
    "RerunLog": "review",
    "SkipEvents": "review",
    "EstimateCodec": "stamped",
    "estimate_values": "stamped",
}

__all__, __getattr__, __dir__ = lazy_face(__name__, _FACE)
