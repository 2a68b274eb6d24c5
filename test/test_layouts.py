"""The Foxglove and PlotJuggler layouts shipped in ``layouts/``: every topic and field they plot
exists in a recording replay writes (and so in the node's, which records the same topics)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import pytest
from helpers import BAGS, ROOT
from mcap.reader import make_reader

from rollergear_ros.core.params import load_config
from rollergear_ros.replay.run import replay
from rollergear_ros.outputs.stamped import ESTIMATE_FIELDS

LAYOUTS = ROOT / "layouts"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> dict[str, str]:
    """Topic -> message type in replay's output of a rig recording with measured output torque."""
    out = tmp_path_factory.mktemp("layouts") / "est.mcap"
    replay(BAGS / "rig_map_drag.mcap", load_config(), out_mcap=out, show_progress=False)
    with out.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    return {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}


def _panels(node) -> list[str]:
    """The panel ids of a Foxglove mosaic layout tree."""
    if isinstance(node, str):
        return [node]
    return _panels(node["first"]) + _panels(node["second"])


def test_the_foxglove_layout_plots_fields_a_recording_has(recorded):
    layout = json.loads((LAYOUTS / "foxglove_rollergear.json").read_text())
    panels = _panels(layout["layout"])
    assert sorted(panels) == sorted(layout["configById"]) and len(panels) >= 4
    plotted = set()
    for panel in panels:
        assert panel.split("!")[0] == "Plot"
        for path in layout["configById"][panel]["paths"]:
            topic, field = path["value"].split(".", 1)
            assert topic in recorded, topic
            if recorded[topic] == "std_msgs/msg/Float64":
                assert field == "data" and path["timestampMethod"] == "receiveTime"
            elif recorded[topic] == "sensor_msgs/msg/Temperature":
                assert field == "temperature"
            else:  # the stamped estimate: position[i] is ESTIMATE_FIELDS[i], at the sample's stamp
                assert recorded[topic] == "sensor_msgs/msg/JointState" and path["timestampMethod"] == "headerStamp"
                index = int(field.removeprefix("position[").removesuffix("]"))
                assert path["label"] == ESTIMATE_FIELDS[index]
            plotted.add(topic)
    assert {t for t in recorded if t.startswith("/rollergear/")} <= plotted  # every input and output has a plot


def test_the_plotjuggler_layout_plots_series_a_recording_has(recorded):
    root = ET.parse(LAYOUTS / "plotjuggler_rollergear.xml").getroot()
    curves = [c.get("name") for c in root.iter("curve")]
    assert len(curves) >= 8
    for name in curves:
        topic = max((t for t in recorded if name.startswith(t + "/")), key=len, default=None)
        assert topic is not None, name
        suffix = name[len(topic) + 1:]
        if recorded[topic] == "std_msgs/msg/Float64":
            assert suffix == "data", name
        elif recorded[topic] == "sensor_msgs/msg/Temperature":
            assert suffix == "temperature", name
        else:  # plotjuggler's JointState parser: <topic>/<joint name>/position
            assert recorded[topic] == "sensor_msgs/msg/JointState", name
            joint, field = suffix.split("/")
            assert joint in ESTIMATE_FIELDS and field == "position", name
    covered = {max((t for t in recorded if n.startswith(t + "/")), key=len) for n in curves}
    assert {t for t in recorded if t.startswith("/rollergear/")} <= covered  # every input and output has a curve
    (selected,) = [e.get("value") for e in root.iter("selected_topics")]
    assert set(selected.split(";")) <= set(recorded)
    assert {n.rsplit("/", 1)[0] for n in curves if n.endswith(("/data", "/temperature"))} <= set(selected.split(";"))
