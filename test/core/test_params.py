"""One typed parameter set: YAML loading, validation with reasons, round trip."""

from __future__ import annotations

import math

import pytest
import yaml

from rollergear_ros.base.errors import ParameterError
from rollergear_ros.core.params import config_to_yaml, load_config, validate
from rollergear_ros.core.paramspecs import parameter_specs

from helpers import CONFIG, run_cli


def test_shipped_yaml_is_the_defaults():
    c = load_config(CONFIG)
    assert c == validate({})


def test_yaml_round_trip(tmp_path):
    c = load_config(overrides={"gearbox.dw_m": 0.005, "effects.drag_speed.enabled": True,
                               "effects.drag_speed.c": 1e-4, "effects.drag_speed.p": 1.5})
    p = tmp_path / "x.yaml"
    p.write_text(config_to_yaml(c))
    assert load_config(p) == c


BAD = [
    ("gearbox.f1", 0.5), ("gearbox.f2", 0.3), ("gearbox.dw_m", 0.0), ("gearbox.dw_m", -0.006),
    ("gearbox.z", 87), ("gearbox.z", 0), ("gearbox.Z", 2.5), ("gearbox.alpha_deg", 90.0),
    ("gearbox.alpha_deg", -1.0), ("gearbox.beta_deg", 95.0), ("gearbox.eta0_pa_s", math.nan),
    ("gearbox.E_eq_pa", math.inf), ("gearbox.Y", 1.5), ("gearbox.mu_m", -0.1), ("gearbox.dm1_m", 0.004),
    ("gearbox.dm2_m", 0.0), ("gearbox.Fg_n", -1.0), ("gearbox.alpha_p_per_pa", 0.0),
    ("gearbox.ellipse_a", "1.1"), ("effects.drag_speed.p", 7.0), ("effects.torque_gain.gain", 0.9),
    ("effects.drag_speed.enabled", 1), ("estimator.staleness_s", 0.0), ("estimator.rls_forgetting", 1.5),
    ("node.input_mode", "serial"), ("node.publish_every_n", 0),
    ("node.rerun_connect", "http://127.0.0.1:9876/proxy"),
]


@pytest.mark.parametrize("name, value", BAD)
def test_every_invalid_parameter_is_rejected_with_its_name(name, value):
    with pytest.raises(ParameterError) as err:
        validate({name: value})
    assert err.value.name == name
    assert name in str(err.value)
    assert repr(value) in str(err.value) or str(value) in str(err.value)


def test_every_numeric_spec_rejects_nan_and_out_of_range():
    for spec in parameter_specs():
        if spec.kind in (int, float):
            with pytest.raises(ParameterError, match=spec.name.replace(".", r"\.")):
                validate({spec.name: math.nan})
            if spec.high is not None:
                with pytest.raises(ParameterError):
                    validate({spec.name: spec.high * 2 + 1})


def test_yaml_with_a_typo_fails(tmp_path):
    doc = yaml.safe_load(CONFIG.read_text())
    node = next(iter(doc))
    doc[node]["ros__parameters"]["gearbox"]["dw_mm"] = doc[node]["ros__parameters"]["gearbox"].pop("dw_m")
    p = tmp_path / "typo.yaml"
    p.write_text(yaml.safe_dump(doc))
    with pytest.raises(ParameterError, match="gearbox.dw_mm"):
        load_config(p)


@pytest.mark.parametrize("text, match", [
    ("just a string", "mapping"),
    ("other_node:\n  ros__parameters: {}\n", "no 'loss_estimator"),
    ("loss_estimator:\n  params: {}\n", "ros__parameters"),
    ("loss_estimator: {ros__parameters: {gearbox: {f1: [1, 2]}}}", "gearbox.f1"),
    ("loss_estimator: [unclosed", "not valid YAML"),
])
def test_malformed_files_give_clear_errors(tmp_path, text, match):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(ParameterError, match=match):
        load_config(p)


@pytest.mark.parametrize("key", ["loss_estimator", "/loss_estimator", "/rollergear/loss_estimator",
                                 "/**/loss_estimator", "/**"])
def test_node_key_spellings_accepted(tmp_path, key):
    p = tmp_path / "k.yaml"
    p.write_text(f"{key}:\n  ros__parameters:\n    gearbox: {{z: 6}}\n    use_sim_time: true\n")
    assert load_config(p).gearbox.z == 6


def test_ints_accepted_for_floats_and_integral_floats_for_ints():
    c = validate({"gearbox.alpha_deg": 20, "gearbox.z": 5.0})
    assert isinstance(c.gearbox.alpha_deg, float) and isinstance(c.gearbox.z, int)


def test_dataclass_defaults_equal_the_spec_defaults():
    """The typed dataclasses repeat the specs' defaults; they must not drift apart."""
    from rollergear_ros.core.params import Config
    from rollergear_ros.core.paramspecs import parameter_specs

    flat = Config().to_flat()
    for spec in parameter_specs():
        assert flat[spec.name] == spec.default, spec.name


@pytest.mark.parametrize(("text", "message"), [
    ("    gearbox: {dw: 0.006}\n", "did you mean 'gearbox.dw_m'?"),
    ("    node: {staleness_s: 0.2}\n", "did you mean 'estimator.staleness_s'?"),
    ("    gearbox: {zzzq: 1}\n", "the keys of 'gearbox' are gearbox.E_eq_pa"),
    ("    nodes: {x: 1}\n", "the sections are calibration, effects, estimator, gearbox, map, node"),
])
def test_a_typo_gets_a_suggestion_not_every_key(tmp_path, text, message):
    from rollergear_ros.base.errors import ParameterError

    p = tmp_path / "p.yaml"
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n" + text)
    with pytest.raises(ParameterError) as err:
        load_config(p)
    assert message in str(err.value) and "known:" not in str(err.value)


def test_broken_yaml_is_one_line_with_file_line_and_column(tmp_path):
    p = tmp_path / "broken.yaml"
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n    gearbox: {dw_m: 0.006\n    estimator: x\n")
    proc = run_cli("model", "--torque", "1", "--speed", "1", "--params", str(p), check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
    assert f"{p}:4:14: not valid YAML" in proc.stderr


def _laughs(levels: int = 9) -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, levels):
        lines.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 10) + "]")
    return "\n".join(lines) + f"\nloss_estimator: {{ros__parameters: {{gearbox: {{dw_m: *a{levels - 1}}}}}}}\n"


@pytest.mark.parametrize(("content", "message"), [
    (_laughs(), "anchors and aliases"),  # a billion laughs: 10^9 strings once expanded (it grew to 8.7 GB)
    ("loss_estimator: " + "[" * 100_000 + "]" * 100_000 + "\n", "nested deeper than 32 levels"),  # RecursionError
    (b"loss_estimator: {ros__parameters: {gearbox: {dw_m: 0.006}}}\n# caf\xe9\n", "not UTF-8 text (byte 0xe9)"),
    ("loss_estimator: {ros__parameters: {gearbox: {dw_m: 0.006}}}\n" + "#" * (1 << 20) + "\n", "larger than 1024 KiB"),
    ("loss_estimator: {ros__parameters: {gearbox: {dw_m: '" + "x" * 200_000 + "'}}}\n", "(200,002 characters)"),
])
def test_hostile_parameter_files_are_one_short_line(tmp_path, content, message):
    """Hostile YAML costs neither memory, recursion nor an endless read, and the error line never
    echoes a huge value."""
    p = tmp_path / "hostile.yaml"
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    proc = run_cli("model", "--torque", "1", "--speed", "1", "--params", str(p), check=False, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert message in proc.stderr and proc.stderr.count("\n") == 1 and len(proc.stderr) < 400, proc.stderr


@pytest.mark.parametrize("target", ["/dev/zero", "directory", "fifo"])
def test_a_parameter_file_that_is_not_a_regular_file_is_refused(tmp_path, target):
    import os

    if target == "directory":
        path = str(tmp_path)
    elif target == "fifo":
        path = str(tmp_path / "params.fifo")
        os.mkfifo(path)
    else:
        path = target
    proc = run_cli("model", "--torque", "1", "--speed", "1", "--params", path, check=False, timeout=120)
    assert proc.returncode == 2 and "is not a regular file" in proc.stderr and proc.stderr.count("\n") == 1


@pytest.mark.parametrize(("url", "ok"), [
    ("", True),
    ("rerun+http://127.0.0.1:9876/proxy", True),
    ("rerun+https://viewer.example.org/proxy", True),
    ("rerun://localhost:9876", True),
    ("rerun+http://127.0.0.1:9876@evil/proxy", False),  # passed the old prefix check; its host is 'evil'
    ("rerun+http://user:pw@127.0.0.1:9876/proxy", False),
    ("rerun+http://127.0.0.1:99999/proxy", False),
    ("rerun+http://127.0.0.1:port/proxy", False),
    ("rerun+http:///proxy", False),
    ("rerun+http://127.0.0.1:9876/pro xy", False),
    ("http://127.0.0.1:9876/proxy", False),
    ("file:///etc/passwd", False),
])
def test_the_rerun_url_is_parsed_not_prefix_matched(url, ok):
    if ok:
        assert validate({"node.rerun_connect": url}).node.rerun_connect == url
    else:
        with pytest.raises(ParameterError, match="node.rerun_connect"):
            validate({"node.rerun_connect": url})


def test_on_and_off_read_as_booleans_are_the_words_where_a_choice_is_on_or_off(tmp_path):
    """YAML 1.1 (ROS parameter files, ``-p node.accept_traced:=on``) reads ``on``/``off`` as booleans."""
    path = tmp_path / "p.yaml"
    path.write_text("/**:\n  ros__parameters:\n    node:\n      accept_traced: on\n", encoding="utf-8")
    assert load_config(path).node.accept_traced == "on"
    assert validate({"node.accept_traced": False}).node.accept_traced == "off"
    with pytest.raises(ParameterError, match="node.input_mode"):  # a choice without on/off takes no boolean
        validate({"node.input_mode": True})


def test_numbers_without_a_dot_read_as_ros2_reads_them(tmp_path):
    """``1e-6`` and ``1e6`` are doubles in a ROS 2 parameter file (rcl); YAML 1.1 would read strings."""
    p = tmp_path / "p.yaml"
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n    map: {torque_step_nm: 1e-1}\n"
                 "    gearbox: {rated_speed_rpm: 1e4}\n    effects:\n"
                 "      drag_speed: {enabled: true, c: 5e-05, p: 1.4}\n")
    config = load_config(p)
    assert config.map.torque_step_nm == 0.1 and config.gearbox.rated_speed_rpm == 1e4
    assert config.effects.params("drag_speed")["c"] == 5e-5
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n    map: {torque_step_nm: '1e-1'}\n")
    with pytest.raises(ParameterError):  # a quoted string stays a string
        load_config(p)


def test_a_split_size_no_file_reaches_is_refused():
    """``node.record_max_mb:=1e-9`` recorded one unsplit file without a word (int(1e-9·1e6) = 0)."""
    with pytest.raises(ParameterError, match="node.record_max_mb"):
        validate({"node.record_max_mb": 1e-9})
    assert validate({"node.record_max_mb": 0.0}).node.record_max_mb == 0.0
    assert validate({"node.record_max_mb": 0.5}).node.record_max_mb == 0.5


def test_the_sequence_clock_is_for_float64_inputs_only():
    """Joint states carry their samples' stamps: a sequence clock asked for them is refused, not ignored."""
    assert validate({"node.sample_clock": "sequence"}).node.sample_clock == "sequence"
    with pytest.raises(ParameterError, match="node.sample_clock.*joint states carry"):
        validate({"node.sample_clock": "sequence", "node.input_mode": "joint_state"})
    with pytest.raises(ParameterError, match="node.sample_clock"):
        validate({"node.sample_clock": "publisher"})


def test_a_file_stating_the_oils_data_sheet_follows_its_law_in_every_command(tmp_path):
    """``gearbox.oil_nu40_mm2_s: 100, oil_nu100_mm2_s: 11`` and nothing of a law: ``model`` at 20 and 80 °C
    gave the same loss; now the data sheet's law (ASTM D341 as Vogel B, C) is the file's, exactly the file that
    states that law, in ``model`` as in the FMU's table and ``predict``; switched off beside it, no oil is
    followed."""
    import json

    from helpers import run_cli

    from rollergear_ros.core.oil import vogel_from_datasheet

    sheet = tmp_path / "sheet.yaml"
    sheet.write_text("/**/loss_estimator:\n  ros__parameters:\n"
                     "    gearbox: {oil_nu40_mm2_s: 100.0, oil_nu100_mm2_s: 11.0}\n")
    b_k, c_k, _ = vogel_from_datasheet(100.0, 11.0, 880.0, theta_ref_c=40.0)
    law = tmp_path / "law.yaml"
    law.write_text(sheet.read_text() + "    effects:\n      viscosity_temperature: {enabled: true, "
                   f"B_k: {round(b_k, 6)!r}, C_k: {round(c_k, 6)!r}, theta_ref_c: 40.0, scale: 1.0}}\n")
    off = tmp_path / "off.yaml"
    off.write_text(sheet.read_text() + "    effects:\n      viscosity_temperature: {enabled: false}\n")

    def loss(params, theta):
        out = run_cli("model", "--params", str(params), "--torque", "50", "--speed", "100", "--oil-temperature-c",
                      str(theta), "--json").stdout
        return json.loads(out)["points"][0]["loss_torque_nm"]

    cold, warm = loss(sheet, 20), loss(sheet, 80)
    assert cold > 2 * warm, (cold, warm)
    assert (cold, warm) == (loss(law, 20), loss(law, 80))
    assert load_config(sheet).effects.derived == ("viscosity_temperature",) and not load_config(law).effects.derived
    assert loss(off, 20) == loss(off, 80)
