"""Shared fixtures; every test run talks DDS on its own domain, on this machine only."""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

from helpers import CONFIG

# property tests draw the same examples on every run: a suite that passes once passes every time
# (a new edge case is found by `--hypothesis-seed=random` runs, not by CI)
settings.register_profile("deterministic", derandomize=True)
settings.load_profile("deterministic")

os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


@pytest.fixture(autouse=True)
def _no_node_outlives_its_test():
    yield
    from rostools import NodeProcess

    NodeProcess.kill_leftovers()


@pytest.fixture(scope="session")
def config():
    from rollergear_ros.params import load_config

    return load_config(CONFIG)
