"""What the estimates become besides the output topics: the stamped estimate's codec, the live
loss map, the VECTO loss map, rerun recordings, and the exported tables.
"""
