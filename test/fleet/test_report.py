"""The fleet report's files: a gearbox id from a recording's metadata never names a file outside the
output folder, and two ids never share one file."""

from __future__ import annotations

import pytest

from rollergear_ros.fleet.report import _write_map, safe_file_name

from helpers import CONFIG

HOSTILE = ["../../ESCAPED", "/tmp/ABSOLUTE", "..", ".", "", ".hidden", "a/b", "a\\b", "line\nbreak", "x" * 300,
           "gb 07", "gb_07~0", "\x1b[2J", "ü"]


def test_safe_ids_are_kept_and_others_become_distinct_names_inside_the_folder():
    assert safe_file_name("gb07") == "gb07" and safe_file_name("rig-3.left_A") == "rig-3.left_A"
    names = [safe_file_name(g) for g in HOSTILE + ["gb07", "gb_07"]]
    assert len(set(names)) == len(names)  # two ids never map to one name
    for name in names:
        assert name and "/" not in name and "\\" not in name and not name.startswith(".") and len(name) <= 120
        assert name.isprintable() and name not in (".", "..")


@pytest.mark.parametrize("gearbox_id", ["../../ESCAPED", "/tmp/rollergear-ABSOLUTE", "maps/../../x"])
def test_a_gearbox_id_that_is_a_path_writes_its_map_inside_the_output_folder(tmp_path, gearbox_id):
    out = tmp_path / "deep" / "out"
    out.mkdir(parents=True)
    relative = _write_map(out, gearbox_id, CONFIG.read_text())
    assert relative is not None
    written = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert written == [out / relative] and (out / relative).parent == out / "maps"
    assert repr(gearbox_id) in (out / relative).read_text()
