"""The node's parameters (rollergear_ros.ros.parameters): declared on an rclpy node of a private context, the
values its parameter files give validated as every command validates a file."""

from __future__ import annotations

import pytest

from rollergear_ros.core.params import load_config


def _declared(overrides: dict):
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from rollergear_ros.ros.parameters import declare_parameters

    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = Node("loss_estimator", context=ctx,
                    parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
        try:
            return declare_parameters(node)
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


@pytest.mark.parametrize("law", [None, False], ids=["data_sheet_only", "law_off"])
def test_the_node_follows_the_oil_of_a_data_sheet_as_the_commands_do(tmp_path, law):
    """Parameters that state the oil's data sheet and nothing of a law: the node's model follows the data
    sheet's law, as ``load_config`` of the same file gives every command; with the law switched off beside it,
    neither follows the oil."""
    sheet = {"gearbox.oil_nu40_mm2_s": 100.0, "gearbox.oil_nu100_mm2_s": 11.0}
    if law is not None:
        sheet["effects.viscosity_temperature.enabled"] = law
    node = _declared(sheet)
    path = tmp_path / "p.yaml"
    path.write_text("/**/loss_estimator:\n  ros__parameters:\n"
                    "    gearbox: {oil_nu40_mm2_s: 100.0, oil_nu100_mm2_s: 11.0}\n"
                    + ("" if law is None else "    effects:\n      viscosity_temperature: {enabled: false}\n"))
    command = load_config(path)
    assert node.to_flat() == command.to_flat()
    assert node.effects.switches.get("viscosity_temperature", False) is (law is None)
