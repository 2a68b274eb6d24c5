"""Shared fixtures; every test run talks DDS on its own domain, on this machine only."""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

from domains import claim_domain
from helpers import CONFIG

# property tests draw the same examples on every run: a suite that passes once passes every time
# (a new edge case is found by `--hypothesis-seed=random` runs, not by CI)
settings.register_profile("deterministic", derandomize=True)
settings.load_profile("deterministic")

# a domain no other session on this machine holds -- also none of this run's other pytest-xdist
# workers, which inherit the controller's environment (the claimer's pid says whose the id is);
# an id the user set is kept (scripts/test then runs the DDS tests one at a time)
_CLAIMER = os.environ.get("ROLLERGEAR_TEST_DOMAIN_PID", str(os.getpid()))
if "ROS_DOMAIN_ID" not in os.environ or _CLAIMER != str(os.getpid()):
    os.environ["ROS_DOMAIN_ID"] = str(claim_domain())
    os.environ["ROLLERGEAR_TEST_DOMAIN_PID"] = str(os.getpid())
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


@pytest.fixture(autouse=True)
def _no_node_outlives_its_test():
    yield
    from rostools import NodeProcess

    NodeProcess.kill_leftovers()


@pytest.fixture(scope="session")
def config():
    from rollergear_ros.core.params import load_config

    return load_config(CONFIG)
