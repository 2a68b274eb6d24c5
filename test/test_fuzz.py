"""A bounded fuzz run over the MCAP reader (through replay), the channel-map/CSV, Parquet, TDMS and
rosbag2 imports and the parameter loader: random truncations, flipped bytes, hostile lengths and
hostile YAML end in a result or one clear error, never a traceback, a hang or unbounded memory, and
every MCAP written is valid.  ``bench/fuzz.py`` runs the same cases for as long as one likes."""

from __future__ import annotations

import pytest

from fuzzer import FILE_TARGETS, Fuzzer

CASES_PER_TARGET = 80  # 11 targets: ~10 s here, under a minute on a machine five times slower
FIRST_TARGETS = ("mcap", "csv", "channel_map", "params")  # they share one random stream


def test_fuzz_the_readers_and_the_parameter_loader(tmp_path):
    fuzzer = Fuzzer(tmp_path, seed=2026)
    report = fuzzer.run(CASES_PER_TARGET)
    assert not report.failures, report.text()
    assert report.cases == len(fuzzer.targets) * CASES_PER_TARGET
    # the cases exercise both ends: damaged inputs that still give a result, and refusals
    for target in ("mcap", "tdms", "parquet", "rosbag2", "outputs"):
        assert report.outcomes.get(f"{target} result", 0) and report.outcomes.get(f"{target} refused", 0), \
            report.text()
    assert report.outcomes.get("params refused", 0) and report.outcomes.get("csv refused", 0), report.text()
    assert report.outcomes.get("rosbag2_kind refused", 0) == CASES_PER_TARGET, report.text()
    assert report.outcomes.get("map_grid refused", 0) and report.outcomes.get("map_grid result", 0), report.text()


@pytest.mark.parametrize(("targets", "seed", "cases", "found"), [
    (FIRST_TARGETS, 1, 3, "a CSV header that is not UTF-8: UnicodeDecodeError"),
    (FIRST_TARGETS, 1, 36, "a channel without its schema record (in a damaged chunk): KeyError copying the inputs"),
    (FIRST_TARGETS, 11, 66, "a damaged summary: OverflowError in the mcap library's summary reader"),
    (FIRST_TARGETS, 14, 62, "a summary whose statistics count a channel it does not define: KeyError"),
    (FILE_TARGETS, 1, 1, "a damaged Parquet page: OSError from pyarrow (corrupt snappy data)"),
    (FILE_TARGETS, 1, 7, "a damaged rosbag2 .db3: apsw.CorruptError while its messages were read"),
    (FILE_TARGETS, 5, 16, "a rosbag2 metadata.yaml nested past the recursion limit: RecursionError"),
])
def test_cases_the_fuzzer_once_found_stay_fixed(tmp_path, targets, seed, cases, found):
    """Each of these runs ends with the case that raised the traceback named in ``found``."""
    fuzzer = Fuzzer(tmp_path, seed=seed)
    fuzzer.targets = {name: case for name, case in fuzzer.targets.items() if name in targets}
    report = fuzzer.run(cases)
    assert not report.failures, f"{found}: {report.text()}"


@pytest.mark.parametrize("what", ["crash", "invalid output"])
def test_the_fuzzer_reports_what_it_is_for(tmp_path, what):
    """The fuzzer itself can fail: a traceback and an invalid output file are reported."""
    fuzzer = Fuzzer(tmp_path, seed=1)

    def crash(k: int) -> str:
        raise KeyError("a defect")

    def invalid_output(k: int) -> str:
        from fuzzer import mcap_output_problem

        bad = tmp_path / "half.mcap"
        bad.write_bytes(fuzzer.seeds["mcap"].read_bytes()[:300])
        problem = mcap_output_problem(bad)
        if problem:
            raise AssertionError(problem)
        return "result"

    fuzzer.targets = {"target": crash if what == "crash" else invalid_output}
    report = fuzzer.run(2)
    assert len(report.failures) == 2 and report.outcomes == {"target crash": 2}, report.text()
