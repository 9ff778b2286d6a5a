"""Shared pytest fixtures.

Every test session runs in its own ROS 2 domain, discovering on this host only: parallel test
runs of several engineers (and CI) on one machine never see each other's nodes, and no DDS
discovery traffic leaves the machine. Child processes inherit the environment.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from feed_twin.ros.domain import private_graph_env, reserve_domain_id


@pytest.fixture(scope="session", autouse=True)
def ros_domain_id() -> Iterator[int]:
    """The ROS_DOMAIN_ID this test session holds; set in os.environ for the whole session."""
    with reserve_domain_id() as domain:
        env = private_graph_env(domain.domain_id)
        saved = {name: os.environ.get(name) for name in env}
        os.environ.update(env)
        try:
            yield domain.domain_id
        finally:
            for name, value in saved.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value


# What feed_twin.ros.dds.init_context rewrites in this process's environment (dds_environment):
# a test that runs nodes in the pytest process must not pass its DDS set-up on to the next test.
_DDS_VARIABLES = (
    "FASTRTPS_DEFAULT_PROFILES_FILE",
    "ROS_AUTOMATIC_DISCOVERY_RANGE",
    "ROS_LOCALHOST_ONLY",
)


@pytest.fixture(autouse=True)
def _dds_environment_restored() -> Iterator[None]:
    saved = {name: os.environ.get(name) for name in _DDS_VARIABLES}
    yield
    for name, value in saved.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
