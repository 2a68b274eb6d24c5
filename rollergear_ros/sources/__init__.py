"""Everything that comes in: the input-format table (``formats``: a reader per format that
``import``, ``replay``, ``calibrate``, ``fleet``, ``play`` and ``info`` all ask), the checks on the
files a command reads and writes (``paths``), rosbag2 and channel-mapped CSV/Parquet/MDF4/TDMS
import, steady-state tables, and ``rollergear info``.
"""

from ..base.face import lazy_face

#: the wing's API (the names other wings use) and the module that defines each
_FACE = {
    "ChannelMap": "channelmap",
    "load_channel_map": "channelmap",
    "input_format": "formats",
    "is_format": "formats",
    "recording_suffixes": "formats",
    "as_mcap": "importer",
    "copy_rosbag2": "importer",
    "import_source": "importer",
    "describe": "info",
    "Output": "paths",
    "check_input_file": "paths",
    "check_outputs": "paths",
    "MIN_ROWS": "tables",
    "SteadyStateTable": "tables",
    "is_table": "tables",
    "read_table": "tables",
}

__all__, __getattr__, __dir__ = lazy_face(__name__, _FACE)
