"""Long fuzz runs: ``python bench/fuzz.py --minutes 30`` mutates MCAP recordings, CSV files with
their channel maps and parameter files until the time is up (test/test_fuzz.py runs a bounded
share of the same cases in the suite).  Prints the cases per second and every failure with its
seed, and exits 1 if there was one.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from fuzzer import FuzzReport, Fuzzer  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=5.0, help="how long to run (default 5)")
    ap.add_argument("--seed", type=int, default=0, help="first seed; each round of 100 cases takes the next")
    args = ap.parse_args()
    report = FuzzReport()
    deadline = time.monotonic() + 60 * args.minutes
    t0 = time.monotonic()
    seed = args.seed
    with tempfile.TemporaryDirectory() as d:
        while time.monotonic() < deadline:
            Fuzzer(Path(d) / str(seed), seed=seed).run(100, report)
            seed += 1
            rate = report.cases / (time.monotonic() - t0)
            print(f"\rseeds {args.seed}..{seed - 1}: {report.cases:,} cases, {rate:.0f}/s, "
                  f"{len(report.failures)} failures", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    print(report.text())
    return 1 if report.failures else 0


if __name__ == "__main__":
    sys.exit(main())
