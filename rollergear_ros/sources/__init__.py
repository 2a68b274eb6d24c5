"""Everything that comes in: the input-format table (``formats``: a reader per format that
``import``, ``replay``, ``calibrate``, ``fleet``, ``play`` and ``info`` all ask), the checks on the
files a command reads and writes (``paths``), rosbag2 and channel-mapped CSV/Parquet/MDF4/TDMS
import, steady-state tables, and ``rollergear info``.
"""
