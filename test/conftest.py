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


#: where every test over DDS (marked ``ros``) lives: one unit of work for scripts/test's scheduling
DDS_FOLDER = "test/ros/"


def pytest_collection_modifyitems(items):
    """The tests over DDS come first (scripts/test's worker that takes them starts at once), and all
    live in :data:`DDS_FOLDER` -- the one unit :func:`pytest_xdist_make_scheduler` keeps together."""
    misplaced = [item.nodeid for item in items
                 if item.get_closest_marker("ros") and not item.nodeid.startswith(DDS_FOLDER)]
    if misplaced:
        raise pytest.UsageError(f"tests marked ros outside {DDS_FOLDER}: {', '.join(misplaced)}")
    items.sort(key=lambda item: not item.nodeid.startswith(DDS_FOLDER))  # stable: each order kept


def pytest_xdist_make_scheduler(config, log):
    """``--dist loadfile`` with the whole of :data:`DDS_FOLDER` as one unit: one pytest-xdist worker
    runs the tests over DDS one at a time (two at once beside a busy loop lost a test's outputs) while the
    other workers take the rest file by file."""
    if config.getoption("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class DdsTogether(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return DDS_FOLDER if nodeid.startswith(DDS_FOLDER) else super()._split_scope(nodeid)

    return DdsTogether(config, log)


@pytest.fixture(autouse=True)
def _no_node_outlives_its_test():
    yield
    from rostools import NodeProcess

    NodeProcess.kill_leftovers()


@pytest.fixture(scope="session")
def config():
    from rollergear_ros.core.params import load_config

    return load_config(CONFIG)


@pytest.fixture
def toy_channel():
    """A toy output channel (the measured loss) registered for the test: one entry of the table
    reaches replay, ``watch`` and the node (test/base/test_outputs.py, test/ros/test_node_outputs.py)."""
    from rollergear_ros.base.interface import MessageType
    from rollergear_ros.base.output_channels import OutputChannel, register, unregister

    toy = OutputChannel("measured_loss", "loss/measured", MessageType.FLOAT64, "N*m",
                        "the measured loss (a toy channel for the table's test)", "measured_loss_nm",
                        measured_only=True)
    register(toy)
    try:
        yield toy
    finally:
        unregister(toy.name)
