"""Instants on a recording's clock (rollergear_ros.base.instants): ISO 8601 to the nanosecond, both ways."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.base.instants import iso_ns, parse_iso_ns


def test_every_stamp_survives_its_iso_text_to_the_nanosecond():
    stamps = np.random.default_rng(0).integers(0, 4_102_444_800 * 10**9, 2000, dtype=np.int64)
    for t in [0, 1, 10**9 - 1, *stamps.tolist()]:
        text = iso_ns(t)
        assert text.endswith("Z") and len(text) == 30 and parse_iso_ns(text) == t, (t, text)


@pytest.mark.parametrize(("text", "ns"), [
    ("2026-12-07T10:00:01Z", 1796637601 * 10**9),
    ("2026-12-07 10:00:01", 1796637601 * 10**9),  # no zone: UTC
    ("2026-12-07T11:00:01+01:00", 1796637601 * 10**9),
    ("2026-12-07T10:00:01.5Z", 1796637601 * 10**9 + 500_000_000),
    ("2026-12-07T10:00:01,000000007Z", 1796637601 * 10**9 + 7),
    ("2026-12-07T10:00Z", 1796637600 * 10**9),
])
def test_iso_forms_a_user_types_are_read(text, ns):
    assert parse_iso_ns(text) == ns


@pytest.mark.parametrize("text", ["12.5", "", "2026-13-07T10:00:01Z", "2026-12-07T10:00:01.1234567891Z",
                                  "2026-12-07", "yesterday"])
def test_what_is_no_instant_is_none(text):
    assert parse_iso_ns(text) is None
