"""The MCAP specification's conformance files read by the package's own reader (``fastmcap``).

Each variant of ``test/data/mcap_conformance`` is written by the ``mcap`` library's writer, set by its
features; its SHA-256 proves the bytes are the conformance file.  The reader must then give every message
the specification lists -- topic, log time, publish time, payload, in file order -- and in log-time order,
with no damage claimed, whichever of chunks, indexes, statistics, summary and repeated records the file
has, and with schemaless channels, metadata and attachments beside the messages.
"""

from __future__ import annotations

import hashlib
import json
from io import BytesIO
from pathlib import Path

import pytest

from helpers import ROOT

DATA = ROOT / "test" / "data" / "mcap_conformance" / "conformance.json"
VARIANTS: dict = json.loads(DATA.read_text())

#: a variant's features -> the writer's index types (``mcap.writer.IndexType`` names)
INDEX_FEATURES = {"ax": "ATTACHMENT", "chx": "CHUNK", "mx": "MESSAGE", "mdx": "METADATA"}


def _fields(record: dict) -> dict:
    return dict(record["fields"])


def _bytes(values: list) -> bytes:
    return bytes(int(v) for v in values)


def conformance_file(name: str) -> bytes:
    """The variant ``name`` written by the ``mcap`` library: records in the specification's order, each
    schema and channel registered once (the writer repeats them where the variant says)."""
    from mcap.writer import CompressionType, IndexType, Writer

    variant = VARIANTS[name]
    features = set(variant["features"])
    index = IndexType.NONE
    for feature, kind in INDEX_FEATURES.items():
        if feature in features:
            index |= getattr(IndexType, kind)
    out = BytesIO()
    writer = Writer(out, index_types=index, compression=CompressionType.NONE, repeat_channels="rch" in features,
                    repeat_schemas="rsh" in features, use_chunking="ch" in features, use_statistics="st" in features,
                    use_summary_offsets="sum" in features, enable_crcs=True, enable_data_crcs=True)
    schemas, channels = set(), set()
    for record in variant["records"]:
        f = _fields(record)
        kind = record["type"]
        if kind == "Header":
            writer.start(f["profile"], f["library"])
        elif kind == "Schema" and f["name"] not in schemas:
            schemas.add(f["name"])
            writer.register_schema(f["name"], f["encoding"], _bytes(f["data"]))
        elif kind == "Channel" and f["topic"] not in channels:
            channels.add(f["topic"])
            writer.register_channel(f["topic"], f["message_encoding"], int(f["schema_id"]), f["metadata"])
        elif kind == "Message":
            writer.add_message(int(f["channel_id"]), int(f["log_time"]), _bytes(f["data"]), int(f["publish_time"]),
                               int(f["sequence"]))
        elif kind == "Attachment":
            writer.add_attachment(int(f["create_time"]), int(f["log_time"]), f["name"], f["media_type"],
                                  _bytes(f["data"]))
        elif kind == "Metadata":
            writer.add_metadata(f["name"], f["metadata"])
    writer.finish()
    return out.getvalue()


def listed_messages(name: str) -> list[tuple[str, int, int, bytes]]:
    """The messages the specification lists for the variant: topic, log time, publish time, payload."""
    topics, messages = {}, []
    for record in VARIANTS[name]["records"]:
        f = _fields(record)
        if record["type"] == "Channel":
            topics[int(f["id"])] = f["topic"]
        elif record["type"] == "Message":
            messages.append((topics[int(f["channel_id"])], int(f["log_time"]), int(f["publish_time"]),
                             _bytes(f["data"])))
    return messages


def test_the_subset_holds_every_family_and_feature():
    families = {name.split("-")[0] for name in VARIANTS}
    assert families == {"NoData", "OneMessage", "OneSchemalessMessage", "TenMessages", "OneMetadata",
                        "OneAttachment"}
    assert set().union(*(v["features"] for v in VARIANTS.values())) == {"ch", "chx", "mx", "st", "sum", "rch",
                                                                        "rsh", "ax", "mdx"}
    assert len(VARIANTS) == 208


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_each_conformance_file_is_read_as_the_specification_lists_it(name, tmp_path):
    from rollergear_ros.recordings.fastmcap import ReadState, iter_message_arrays
    from rollergear_ros.recordings.logorder import iter_log_time_order

    data = conformance_file(name)
    # the bytes are the conformance file, not a look-alike
    assert (hashlib.sha256(data).hexdigest(), len(data)) == (VARIANTS[name]["sha256"], VARIANTS[name]["size"])
    path = tmp_path / f"{name}.mcap"
    path.write_bytes(data)
    expected = listed_messages(name)
    state = ReadState()
    got = [(state.channels[int(a.channel[i])][0], int(a.log_time[i]), int(a.publish_time[i]), a.payload(i))
           for a in iter_message_arrays(path, state) for i in range(len(a))]
    assert got == expected
    assert not state.damaged and not state.truncated and not state.bad_log_times, state.problem
    # in log-time order (file order among equal times): topic, log time, payload
    state = ReadState()
    got = [(state.channels[int(c)][0], int(t), p) for times, ids, payloads in iter_log_time_order(path, state)
           for t, c, p in zip(times, ids, payloads)]
    assert got == [(topic, t, p) for topic, t, _, p in sorted(expected, key=lambda m: m[1])]
    assert not state.damaged and not state.truncated, state.problem

def test_a_variant_written_otherwise_is_not_taken_for_the_conformance_file():
    """The SHA-256 check can fail: the same records written with another feature set differ."""
    name = "TenMessages-ch-chx-mx-st-sum"
    original = dict(VARIANTS[name])
    try:
        VARIANTS[name] = {**original, "features": [f for f in original["features"] if f != "st"]}
        assert hashlib.sha256(conformance_file(name)).hexdigest() != original["sha256"]
    finally:
        VARIANTS[name] = original


def test_the_data_came_with_its_license():
    assert "MIT License" in (Path(DATA).parent / "LICENSE").read_text()
