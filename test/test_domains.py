"""Two test sessions on one machine never share a DDS domain (test/domains.py)."""

from __future__ import annotations

import subprocess
import sys

from domains import DOMAINS, claim_domain
from helpers import ROOT


def test_a_claimed_domain_is_not_given_again_while_held(tmp_path):
    first, second = claim_domain(tmp_path), claim_domain(tmp_path)
    assert first != second and first in DOMAINS and second in DOMAINS
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from domains import claim_domain; "
            "print(claim_domain(sys.argv[2]))")
    other = int(subprocess.run([sys.executable, "-c", code, str(ROOT / "test"), str(tmp_path)],
                               capture_output=True, text=True, check=True).stdout)
    assert other not in (first, second)  # another process: neither of this one's


def test_every_domain_taken_is_one_clear_error(tmp_path, monkeypatch):
    import domains

    monkeypatch.setattr(domains, "DOMAINS", range(150, 152))
    taken = {domains.claim_domain(tmp_path), domains.claim_domain(tmp_path)}
    assert taken == {150, 151}
    try:
        domains.claim_domain(tmp_path)
    except RuntimeError as exc:
        assert "every DDS domain 150..151 is taken" in str(exc)
    else:
        raise AssertionError("a third claim of two domains succeeded")
