"""ROS 2 MCAP recordings without ROS: reading (the numpy chunk parser, damage handling),
writing (chunked, time-ordered, atomic) and the CDR codec.  Imports ``base`` and ``core``.
"""
