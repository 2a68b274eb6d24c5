"""The base: names other tools depend on (``interface``), the output-channel table
(``output_channels``), the one exception family (``errors``), safe YAML, atomic file writing,
progress bars, graceful stopping, text from files made safe to show (``text``) and instants on a
recording's clock to the nanosecond (``instants``).  Imports nothing else of the package.
"""

from .face import lazy_face

#: the wing's API (the names other wings use) and the module that defines each
_FACE = {
    "lazy_face": "face",
    "Instant": "instants",
    "iso_ns": "instants",
    "parse_iso_ns": "instants",
    "commit": "atomic",
    "discard": "atomic",
    "named": "atomic",
    "partial_path": "atomic",
    "replacing": "atomic",
    "save_figure": "atomic",
    "together": "atomic",
    "write_text": "atomic",
    "BagError": "errors",
    "InputFileError": "errors",
    "ParameterError": "errors",
    "RollergearError": "errors",
    "UsageError": "errors",
    "damage_totals": "errors",
    "damaged_exit": "errors",
    "lost_share": "errors",
    "Channel": "interface",
    "MessageType": "interface",
    "Metadata": "interface",
    "MAX_QUEUE_DEPTH": "interface",
    "NAMESPACE": "interface",
    "NODE_NAME": "interface",
    "OUTPUT_QUEUE_DEPTH": "interface",
    "RAD_S_PER_RPM": "interface",
    "RPM_PER_RAD_S": "interface",
    "Topic": "interface",
    "package_version": "interface",
    "printable": "text",
    "OUTPUT_CHANNELS": "output_channels",
    "OutputChannel": "output_channels",
    "float64_channels": "output_channels",
    "map_channels": "output_channels",
    "stamped_channels": "output_channels",
    "trace_channels": "output_channels",
    "window_channels": "output_channels",
    "TimedProgress": "progress",
    "YamlProblem": "safeyaml",
    "load": "safeyaml",
    "GracefulStop": "stopping",
    "children_spared_interrupts": "stopping",
}

__all__, __getattr__, __dir__ = lazy_face(__name__, _FACE)
