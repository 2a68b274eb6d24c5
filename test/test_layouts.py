"""The Foxglove and PlotJuggler layouts shipped in ``layouts/``: every topic and field they plot
exists in a recording replay writes; those only the node has (``/diagnostics``, the online trace)
in the node's own recording (``test/ros/test_recordings.py``, through :func:`check_node_topics`)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import pytest
from helpers import BAGS, ROOT
from mcap.reader import make_reader

from rollergear_ros.core.params import load_config
from rollergear_ros.outputs.stamped import ESTIMATE_FIELDS
from rollergear_ros.replay.run import replay

LAYOUTS = ROOT / "layouts"
#: what only the node records: its status and the online trace's results
NODE_ONLY = ("/diagnostics", "/rollergear/loss/traced")


def foxglove() -> dict:
    return json.loads((LAYOUTS / "foxglove_rollergear.json").read_text())


def plotjuggler_curves() -> list[str]:
    return [c.get("name") for c in ET.parse(LAYOUTS / "plotjuggler_rollergear.xml").getroot().iter("curve")]


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
    layout = foxglove()
    panels = _panels(layout["layout"])
    assert sorted(panels) == sorted(layout["configById"]) and len(panels) >= 4
    kinds = {p.split("!")[0] for p in panels}
    assert {"Plot", "DiagnosticSummary", "DiagnosticStatusPanel", "RawMessages"} <= kinds
    plotted = set()
    for panel in panels:
        config = layout["configById"][panel]
        if not panel.startswith("Plot!"):  # the status panels and the trace's: node-only topics
            assert (config.get("topicToRender") or config.get("topicPath")) in NODE_ONLY, panel
            continue
        for path in config["paths"]:
            topic, field = path["value"].split(".", 1)
            assert topic in recorded, topic
            if recorded[topic] == "std_msgs/msg/Float64":
                assert field == "data" and path["timestampMethod"] == "receiveTime"
            elif recorded[topic] == "sensor_msgs/msg/Temperature":
                assert field == "temperature"
            else:  # the stamped estimate: position[i] is ESTIMATE_FIELDS[i], at the sample's stamp
                assert recorded[topic] == "sensor_msgs/msg/JointState" and path["timestampMethod"] == "headerStamp"
                index = int(field.removeprefix("position[").removesuffix("]"))
                assert path["label"].endswith(f"({ESTIMATE_FIELDS[index]})") or path["label"] == ESTIMATE_FIELDS[index]
            plotted.add(topic)
    assert {t for t in recorded if t.startswith("/rollergear/")} <= plotted  # every input and output has a plot
    assert "/rollergear/efficiency/measured" in plotted and "/rollergear/efficiency/measured_uncertainty" in plotted


def test_the_plotjuggler_layout_plots_series_a_recording_has(recorded):
    root = ET.parse(LAYOUTS / "plotjuggler_rollergear.xml").getroot()
    curves = plotjuggler_curves()
    assert len(curves) >= 8
    for name in curves:
        if name.startswith(NODE_ONLY):
            continue
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
    covered = {max((t for t in recorded if n.startswith(t + "/")), key=len)
               for n in curves if not n.startswith(NODE_ONLY)}
    assert {t for t in recorded if t.startswith("/rollergear/")} <= covered  # every input and output has a curve
    assert any(n.startswith(NODE_ONLY) for n in curves)
    (selected,) = [e.get("value") for e in root.iter("selected_topics")]
    assert set(selected.split(";")) <= set(recorded) | set(NODE_ONLY)
    assert {n.rsplit("/", 1)[0] for n in curves if n.endswith(("/data", "/temperature"))} <= set(selected.split(";"))


def check_node_topics(recording: dict) -> None:
    """The layouts' node-only topics and fields in a node's recording (topic -> (times, decoded
    messages), :func:`bagtools.read_mcap_ros2`): the status panels' hardware id and name, each
    /diagnostics series PlotJuggler makes of a key whose value is a number, the trace's level."""
    statuses = [s for m in recording["/diagnostics"][1] for s in m.status]
    for panel, config in foxglove()["configById"].items():
        if panel.startswith("DiagnosticStatusPanel!"):
            assert any(s.hardware_id == config["selectedHardwareId"] and s.name == config["selectedName"]
                       for s in statuses), config
        elif panel.startswith("RawMessages!"):
            assert recording[config["topicPath"]][1], config["topicPath"]
    for name in plotjuggler_curves():
        if name.startswith("/diagnostics/"):  # /diagnostics/<hardware_id>/<status name>/<key>
            hardware_id, status_name, key = name.removeprefix("/diagnostics/").split("/", 2)
            values = [kv.value for s in statuses if s.hardware_id == hardware_id and s.name == status_name
                      for kv in s.values if kv.key == key]
            assert values and all(_number(v) for v in values[-3:]), (name, values[-3:])
        elif name.startswith("/rollergear/loss/traced/"):
            field = name.removeprefix("/rollergear/loss/traced/")
            assert recording["/rollergear/loss/traced"][1] and hasattr(recording["/rollergear/loss/traced"][1][0],
                                                                      field), name


def _number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
