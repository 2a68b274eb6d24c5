"""Shared fixtures; every test run talks DDS on its own domain, on this machine only."""

from __future__ import annotations

import os

import pytest

from helpers import CONFIG

os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


@pytest.fixture(scope="session")
def config():
    from rollergear_ros.params import load_config

    return load_config(CONFIG)
