"""A small mutation fuzzer over what users hand the package: MCAP recordings, channel-mapped CSV,
Parquet and TDMS files with their channel maps, rosbag2 bags (metadata.yaml and the SQLite file)
and parameter files.

Each case mutates a valid seed file (truncation, flipped bytes, hostile 64-bit lengths, inserted
or repeated bytes; hostile YAML constructs for YAML files) and runs the package's own entry
point on it.  A case passes when it ends in a result or one of the package's errors
(:class:`~rollergear_ros.base.errors.RollergearError`, one clear line for the user), within its time
bound, with the process's peak memory within a bound, and with every output file it wrote valid
(an MCAP with its summary, readable by the ``mcap`` library).  Used by ``test/test_fuzz.py``
(bounded) and ``bench/fuzz.py`` (long runs).
"""

from __future__ import annotations

import resource
import signal
import struct
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rollergear_ros.base.errors import RollergearError

CASE_TIMEOUT_S = 30  #: a case running longer is a hang (the seeds take milliseconds)
RSS_BOUND_MB = 1024  #: peak memory may grow at most this much over a whole run
#: targets that draw from ``Fuzzer.file_rng``
FILE_TARGETS = ("tdms", "parquet", "rosbag2")
#: targets that draw from ``Fuzzer.surface_rng``: the output checks of folder inputs, report folders
#: and the node's files, fleet ids as file names, loss-map grids, rosbag2 storage kinds
SURFACE_TARGETS = ("outputs", "fleet_id", "map_grid", "rosbag2_kind")
#: paths an output may be given as (``{bag}``: a rosbag2 folder input, ``{rep}``: a report folder
#: holding an input); the case asserts no input changed, whatever it decided
HOSTILE_OUTPUTS = ("{bag}/seed_rosbag2.db3", "{bag}/metadata.yaml", "{bag}", "{bag}/new.mcap", "{bag}/../x.mcap",
                   "{rep}", "{rep}/report.md", "", " ", "/proc/x.mcap", "/dev/null", "{fifo}", "{d}/a/../b.mcap",
                   "{d}/o.png", "{d}/o", "{d}/o.mcap")
HOSTILE_IDS = ("../../ESCAPED", "/etc/passwd", "..", ".", "", ".hidden", "a/b", "a\\b", "x\ny", "\x1b[2J", "gb~1",
               "gb_07", "ü", "x" * 300, "CON", "a b", "gb07")

HOSTILE_U64 = (2**63, 2**64 - 1, 2**32, 2**31 - 1, 1 << 40, 0)
HOSTILE_YAML = (
    "&a [*a, *a]", "*undefined", "[" * 2000, "{" * 2000, "!!python/object:os.system ls", "'" + "x" * 100_000 + "'",
    "\x00", "\ufeff", "? [a, b]\n: c", "<<: *a", "1e999999", "-.inf", ".nan", "0x" + "f" * 64, "[" * 40 + "]" * 40,
)


@dataclass
class FuzzReport:
    """What a run did: cases per target and outcome, and the failures with their reproduction."""

    cases: int = 0
    outcomes: dict[str, int] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    max_case_s: float = 0.0

    def add(self, outcome: str) -> None:
        self.outcomes[outcome] = self.outcomes.get(outcome, 0) + 1

    def text(self) -> str:
        counts = ", ".join(f"{k}: {v}" for k, v in sorted(self.outcomes.items()))
        return (f"{self.cases} cases ({counts}); slowest {self.max_case_s:.2f} s; "
                f"{len(self.failures)} failures" + "".join(f"\n  {f}" for f in self.failures[:10]))


def mutate_bytes(data: bytes, rng: np.random.Generator) -> bytes:
    """One random structural mutation of a binary file."""
    b = bytearray(data)
    kind = rng.integers(6)
    if kind == 0 and len(b) > 1:  # truncation
        return bytes(b[:rng.integers(0, len(b))])
    if kind == 1:  # a few flipped bytes
        for _ in range(rng.integers(1, 9)):
            i = int(rng.integers(len(b)))
            b[i] ^= 1 << int(rng.integers(8))
        return bytes(b)
    if kind == 2 and len(b) > 8:  # a hostile 64-bit length or time at a random offset
        i = int(rng.integers(0, len(b) - 8))
        b[i:i + 8] = struct.pack("<Q", HOSTILE_U64[int(rng.integers(len(HOSTILE_U64)))])
        return bytes(b)
    if kind == 3:  # random bytes inserted
        i = int(rng.integers(len(b) + 1))
        return bytes(b[:i]) + rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8).tobytes() + bytes(b[i:])
    if kind == 4 and len(b) > 2:  # a slice repeated
        i, j = sorted(int(x) for x in rng.integers(0, len(b), 2))
        return bytes(b[:j]) + bytes(b[i:j]) + bytes(b[j:])
    return bytes(b[:8]) + rng.integers(0, 256, int(rng.integers(0, 4096)), dtype=np.uint8).tobytes()  # garbage


def mutate_text(text: str, rng: np.random.Generator) -> bytes:
    """A YAML/CSV text mutation: a hostile construct spliced in at a line, or a byte mutation."""
    if rng.random() < 0.5:
        lines = text.splitlines()
        i = int(rng.integers(len(lines) + 1))
        piece = HOSTILE_YAML[int(rng.integers(len(HOSTILE_YAML)))]
        if rng.random() < 0.5 and lines:
            lines[min(i, len(lines) - 1)] += " " + piece
        else:
            lines.insert(i, piece)
        return ("\n".join(lines) + "\n").encode("utf-8", errors="surrogatepass")
    return mutate_bytes(text.encode(), rng)


def mcap_output_problem(path: Path) -> str | None:
    """Why a written MCAP is not valid (None: it has its summary and the ``mcap`` reader reads it)."""
    from mcap.reader import make_reader

    if not path.exists():
        return None
    try:
        with path.open("rb") as fh:
            reader = make_reader(fh)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                return "no summary"
            n = sum(1 for _ in reader.iter_messages())
            if n != summary.statistics.message_count:
                return f"{n} messages read, the summary counts {summary.statistics.message_count}"
    except Exception as exc:  # noqa: BLE001 - any reader error means an invalid output
        return f"unreadable ({type(exc).__name__}: {exc})"
    return None


def _writes_valid_mcap(out: Path, write: Callable[[], object]) -> str:
    """Run ``write``, which may write the MCAP ``out``: whatever it wrote, also when it raised, must
    be valid (the file is removed afterwards)."""
    try:
        write()
    finally:
        problem = mcap_output_problem(out)
        out.unlink(missing_ok=True)
        if problem:
            raise AssertionError(f"invalid output MCAP {out.name}: {problem}")
    return "result"


class _Timeout(Exception):
    pass


def _alarm(signum, frame) -> None:  # noqa: ARG001
    raise _Timeout


class Fuzzer:
    """Runs cases against the targets; ``workdir`` holds the seeds and each case's files."""

    def __init__(self, workdir: Path, seed: int = 0) -> None:
        from rollergear_ros.core.params import load_config

        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.rng = np.random.default_rng(seed)
        # the file formats added later draw from a stream of their own, so the first targets' cases
        # (and the seeds that once found a defect in them) stay what they were
        self.file_rng = np.random.default_rng([seed, 1])
        self.surface_rng = np.random.default_rng([seed, 2])
        self.ids: dict[str, str] = {}  # fleet_id: file name -> the id it came from (never two ids)
        self.seed = seed
        self.config = load_config(None)
        self.seeds = _write_seeds(self.workdir)
        self.targets: dict[str, Callable[[int], str]] = {
            "mcap": self._mcap_case, "csv": self._csv_case, "channel_map": self._channel_map_case,
            "params": self._params_case, "tdms": self._tdms_case, "parquet": self._parquet_case,
            "rosbag2": self._rosbag2_case, "outputs": self._outputs_case, "fleet_id": self._fleet_id_case,
            "map_grid": self._map_grid_case, "rosbag2_kind": self._rosbag2_kind_case}

    # ------------------------------------------------------------------ targets
    def _mcap_case(self, k: int) -> str:
        from rollergear_ros.replay.run import replay

        src = self.workdir / f"case{k}.mcap"
        src.write_bytes(mutate_bytes(self.seeds["mcap"].read_bytes(), self.rng))
        out = self.workdir / f"case{k}_out.mcap"
        return _writes_valid_mcap(out, lambda: replay(src, self.config, out_mcap=out, show_progress=False,
                                                      warn=lambda m: None))

    def _import(self, csv: Path, cmap: Path, k: int) -> str:
        from rollergear_ros.sources.importer import import_source

        out = self.workdir / f"case{k}_import.mcap"
        return _writes_valid_mcap(out, lambda: import_source(csv, out, cmap))

    def _csv_case(self, k: int) -> str:
        csv = self.workdir / f"case{k}.csv"
        csv.write_bytes(mutate_text(self.seeds["csv"].read_text(), self.rng))
        return self._import(csv, self.seeds["channel_map"], k)

    def _channel_map_case(self, k: int) -> str:
        cmap = self.workdir / f"case{k}_map.yaml"
        cmap.write_bytes(mutate_text(self.seeds["channel_map"].read_text(), self.rng))
        return self._import(self.seeds["csv"], cmap, k)

    def _params_case(self, k: int) -> str:
        from rollergear_ros.core.params import load_config

        p = self.workdir / f"case{k}_params.yaml"
        p.write_bytes(mutate_text(self.seeds["params"].read_text(), self.rng))
        load_config(p)
        return "result"

    def _tdms_case(self, k: int) -> str:
        """A TDMS file with damaged bytes (its lead-ins, properties such as wf_increment, data)."""
        src = self.workdir / f"case{k}.tdms"
        src.write_bytes(mutate_bytes(self.seeds["tdms"].read_bytes(), self.file_rng))
        return self._import(src, self.seeds["tdms_map"], k)

    def _parquet_case(self, k: int) -> str:
        """A Parquet file with damaged bytes (footer, page headers, compressed pages)."""
        src = self.workdir / f"case{k}.parquet"
        src.write_bytes(mutate_bytes(self.seeds["parquet"].read_bytes(), self.file_rng))
        return self._import(src, self.seeds["channel_map"], k)

    def _rosbag2_case(self, k: int) -> str:
        """A rosbag2 folder whose metadata.yaml (text) or .db3 (bytes) is damaged, imported to MCAP."""
        import shutil

        from rollergear_ros.sources.importer import import_source

        bag = self.workdir / f"case{k}_rosbag2"
        shutil.copytree(self.seeds["rosbag2"], bag)
        target = bag / ("metadata.yaml" if self.file_rng.random() < 0.5 else "seed_rosbag2.db3")
        if target.suffix == ".yaml":
            target.write_bytes(mutate_text(target.read_text(), self.file_rng))
        else:
            target.write_bytes(mutate_bytes(target.read_bytes(), self.file_rng))
        out = self.workdir / f"case{k}_rosbag2.mcap"
        return _writes_valid_mcap(out, lambda: import_source(bag, out, None))

    def _outputs_case(self, k: int) -> str:
        """A command's outputs drawn from :data:`HOSTILE_OUTPUTS` against a rosbag2 folder input and a
        report folder: refused or accepted, never an input changed (the check writes nothing)."""
        import os
        import shutil

        from rollergear_ros.calibration.report import REPORT_FILES
        from rollergear_ros.sources.paths import Output, check_outputs

        d = self.workdir / f"case{k}_outputs"
        bag, rep, fifo = d / "bag", d / "rep", d / "fifo"
        shutil.copytree(self.seeds["rosbag2"], bag)
        rep.mkdir()
        (rep / "report.md").write_text("an input")
        os.mkfifo(fifo)
        before = {p: p.read_bytes() for p in d.rglob("*") if p.is_file()}
        rng = self.surface_rng
        kinds = ("mcap", "csv", "yaml", "folder")
        outputs = [Output(f"--o{j}", HOSTILE_OUTPUTS[rng.integers(len(HOSTILE_OUTPUTS))].format(
            bag=bag, rep=rep, fifo=fifo, d=d), kinds[rng.integers(len(kinds))], REPORT_FILES)
            for j in range(int(rng.integers(1, 4)))]
        try:
            check_outputs([bag, rep / "report.md"], outputs)
        finally:
            assert {p: p.read_bytes() for p in d.rglob("*") if p.is_file()} == before, "an input changed"
        return "result"

    def _fleet_id_case(self, k: int) -> str:  # noqa: ARG002
        """A gearbox id from :data:`HOSTILE_IDS`, spliced: its file name stays in the folder and
        belongs to it alone."""
        from rollergear_ros.fleet.report import safe_file_name

        rng = self.surface_rng
        gid = "".join(HOSTILE_IDS[rng.integers(len(HOSTILE_IDS))] for _ in range(int(rng.integers(1, 3))))
        name = safe_file_name(gid)
        assert name and "/" not in name and "\\" not in name and name not in (".", "..") and not name.startswith(".")
        assert name.isprintable() and len(name) <= 120, repr(name)
        assert self.ids.setdefault(name, gid) == gid, f"{gid!r} and {self.ids[name]!r} share {name!r}"
        return "result"

    def _map_grid_case(self, k: int) -> str:  # noqa: ARG002
        """A loss map over a random grid (steps from 1e-9 to 1e6): refused or built, within the time
        and memory bounds."""
        from rollergear_ros.outputs.lossmap import build_map, grid

        rng = self.surface_rng
        speeds = grid(0.0, float(10 ** rng.uniform(0, 7)), float(10 ** rng.uniform(-9, 6)))
        torques = grid(-float(10 ** rng.uniform(0, 4)), float(10 ** rng.uniform(0, 4)), float(10 ** rng.uniform(-9, 4)))
        if len(speeds) * len(torques) > 20_000:  # within the cap: built by the map test, not in each case
            return "result"
        build_map(self.config, speeds, torques)
        return "result"

    def _rosbag2_kind_case(self, k: int) -> str:
        """A rosbag2 folder whose storage file is a FIFO, missing, "zstd-compressed" garbage, or whose
        metadata.yaml has anchors, imported."""
        import os
        import shutil

        from rollergear_ros.sources.importer import import_source

        bag = self.workdir / f"case{k}_kind"
        shutil.copytree(self.seeds["rosbag2"], bag)
        meta = bag / "metadata.yaml"
        kind = int(self.surface_rng.integers(4))
        if kind == 0:
            (bag / "seed_rosbag2.db3").unlink()
            os.mkfifo(bag / "seed_rosbag2.db3")
        elif kind == 1:
            (bag / "seed_rosbag2.db3").unlink()
        elif kind == 2:
            (bag / "seed_rosbag2.db3.zstd").write_bytes(self.surface_rng.bytes(4096))
            meta.write_text(meta.read_text().replace("seed_rosbag2.db3", "seed_rosbag2.db3.zstd")
                            .replace("compression_format: ''", "compression_format: zstd")
                            .replace("compression_mode: ''", "compression_mode: FILE"))
        else:
            meta.write_text(meta.read_text() + "x_anchor: &a [1]\nx_alias: *a\n")
        out = self.workdir / f"case{k}_kind.mcap"
        return _writes_valid_mcap(out, lambda: import_source(bag, out, None))

    # ------------------------------------------------------------------ running
    def run(self, cases_per_target: int, report: FuzzReport | None = None) -> FuzzReport:
        report = report or FuzzReport()
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        old = signal.signal(signal.SIGALRM, _alarm)
        try:
            for k in range(cases_per_target):
                for name, case in self.targets.items():
                    rng = (self.file_rng if name in FILE_TARGETS else self.surface_rng if name in SURFACE_TARGETS
                           else self.rng)
                    state = rng.bit_generator.state  # to reproduce a failure
                    t0 = time.perf_counter()
                    signal.alarm(CASE_TIMEOUT_S)
                    try:
                        outcome = case(k)
                    except RollergearError:
                        outcome = "refused"
                    except _Timeout:
                        outcome = "hang"
                        report.failures.append(f"{name} case {k} (seed {self.seed}): no result in {CASE_TIMEOUT_S} s")
                    except Exception as exc:  # noqa: BLE001 - anything else is what the fuzzer looks for
                        outcome = "crash"
                        tb = traceback.format_exception(exc)[-3:]
                        report.failures.append(f"{name} case {k} (seed {self.seed}, rng state "
                                               f"{state['state']['state']}): {''.join(tb).strip()}")
                    finally:
                        signal.alarm(0)
                    report.max_case_s = max(report.max_case_s, time.perf_counter() - t0)
                    report.cases += 1
                    report.add(f"{name} {outcome}")
                grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024
                if grown_mb > RSS_BOUND_MB:
                    report.failures.append(f"peak memory grew {grown_mb:.0f} MB (bound {RSS_BOUND_MB} MB) by case {k}")
                    break
        finally:
            signal.signal(signal.SIGALRM, old)
        return report


def _write_seeds(workdir: Path) -> dict[str, Path]:
    """Small valid inputs: a recording of three chunks, a CSV with its channel map, the parameter file."""
    from rollergear_ros.recordings.bagwriter import BagWriter
    from rollergear_ros.recordings.messages import TopicMap

    tm = TopicMap()
    n = 600
    t = 10**18 + np.arange(n, dtype=np.int64) * 10_000_000
    bag = workdir / "seed.mcap"
    with BagWriter(bag, chunk_size=8 * 1024) as bw:
        for k in range(0, n, 100):
            sl = slice(k, k + 100)
            bw.write_float64_series(tm.motor_torque, t[sl], 20 + 10 * np.sin(np.arange(n)[sl] / 50))
            bw.write_float64_series(tm.motor_speed, t[sl], np.full(100, 150.0))
            bw.write_float64_series(tm.output_torque, t[sl], np.full(100, -27.0))
    csv = workdir / "seed.csv"
    rows = ["t_ms,T_in,n_in,T_out"] + [f"{k * 10},{20000 + 5 * k},{1400 + k % 7},{-27.1}" for k in range(200)]
    csv.write_text("\n".join(rows) + "\n")
    cmap = workdir / "seed_map.yaml"
    cmap.write_text("format: timeseries\ntime: {column: t_ms, unit: ms}\nmotor_torque: {column: T_in, unit: N*mm}\n"
                    "motor_speed: {column: n_in, unit: rpm}\noutput_torque: {column: T_out, unit: N*m}\nratio: 1.368\n")
    params = workdir / "seed_params.yaml"
    params.write_text((Path(__file__).resolve().parents[1] / "config" / "gearbox.yaml").read_text())
    return {"mcap": bag, "csv": csv, "channel_map": cmap, "params": params, **_write_file_seeds(workdir, csv, bag)}


def _write_file_seeds(workdir: Path, csv: Path, bag: Path) -> dict[str, Path]:
    """The CSV's rows as Parquet (pyarrow) and as TDMS waveforms (nptdms, with its channel map); the
    recording as a rosbag2 SQLite bag (rosbags' writer)."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq
    from mcap.reader import make_reader
    from nptdms import ChannelObject, TdmsWriter
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    table = pacsv.read_csv(csv)
    parquet = workdir / "seed.parquet"
    pq.write_table(table, parquet, row_group_size=64)
    tdms = workdir / "seed.tdms"
    with TdmsWriter(tdms) as writer:
        writer.write_segment([ChannelObject("rig", name, table[name].to_numpy().astype(float),
                                            properties={"wf_increment": 0.01, "wf_start_offset": 0.0})
                              for name in ("T_in", "n_in", "T_out")])
    tdms_map = workdir / "seed_tdms_map.yaml"
    tdms_map.write_text("motor_torque: {column: rig/T_in, unit: N*mm}\nmotor_speed: {column: rig/n_in, unit: rpm}\n"
                        "output_torque: {column: rig/T_out, unit: N*m}\nratio: 1.368\n")
    rosbag2 = workdir / "seed_rosbag2"
    store = get_typestore(Stores.ROS2_JAZZY)
    with Writer(rosbag2, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer, bag.open("rb") as fh:
        conns = {}
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            if channel.topic not in conns:
                conns[channel.topic] = writer.add_connection(channel.topic, schema.name, typestore=store)
            writer.write(conns[channel.topic], message.log_time, message.data)
    return {"parquet": parquet, "tdms": tdms, "tdms_map": tdms_map, "rosbag2": rosbag2}


__all__ = ["FILE_TARGETS", "SURFACE_TARGETS", "FuzzReport", "Fuzzer", "mcap_output_problem", "mutate_bytes",
           "mutate_text"]
