"""ROS 2 MCAP recordings without ROS, by concern: ``records`` (every record framed by hand, its read and
write side by side), ``messages`` (definitions, the topic map, the CDR codec), ``baginfo`` (what a bag
holds, its metadata, raw messages), ``bagwriter`` (writing), ``fastmcap`` (the one chunk reader),
``damage`` (what a read skipped, where it resumed), ``logorder`` (messages in log-time order),
``layout`` (message records laid out for whole arrays; the optional C kernel ``_records`` lays out the
same bytes), ``mcapwriter`` (the chunked writer), ``timeorder`` (messages handed to it in log-time
order), ``rolling`` (a recording split by size and age).  Imports ``base`` only.
"""

from ..base.face import lazy_face

#: the wing's API (the names other wings use) and the module that defines each
_FACE = {
    "BagInfo": "baginfo",
    "RawBatch": "baginfo",
    "SUMMARY_ERRORS": "baginfo",
    "inspect_bag": "baginfo",
    "iter_raw_batches": "baginfo",
    "median_period_s": "baginfo",
    "read_metadata": "baginfo",
    "BagWriter": "bagwriter",
    "offered_qos_yaml": "bagwriter",
    "ReadState": "fastmcap",
    "byte_rows": "records",
    "iter_log_time_order": "logorder",
    "iter_message_arrays": "fastmcap",
    "preload_summary": "fastmcap",
    "release_count": "logorder",
    "CDR_LE_HEADER": "messages",
    "MSG_DEFINITIONS": "messages",
    "TopicMap": "messages",
    "cdr_problem": "messages",
    "decode_float64": "messages",
    "decoder_for": "messages",
    "encode_float64": "messages",
    "encoder_for": "messages",
    "float64_payloads": "messages",
    "float64_problem": "messages",
    "stamp": "messages",
    "temperature_payloads": "messages",
    "RollingRecorder": "rolling",
    "free_name": "rolling",
    "is_template": "rolling",
    "next_file": "rolling",
    "roll_due": "rolling",
    "splits": "rolling",
    "template_problem": "rolling",
}

__all__, __getattr__, __dir__ = lazy_face(__name__, _FACE)
