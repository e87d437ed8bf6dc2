"""The tests sharing a module's fixture run in one pytest-xdist worker (``conftest.py``'s
``group_by_module_fixtures``), so the fixture (a whole run, an emulator process, a browser) is
set up once, not once per worker: the group reaches pytest-xdist, which names it in the test's
id (``<node id>@<group>``) when it distributes by group (``--dist loadgroup``, the default
run's). Run in one process (``-n 0``) there are no groups to distribute, and no suffix."""

from __future__ import annotations

import os

import pytest


@pytest.fixture(scope="module")
def shared() -> str:
    return "set up once per module"


def _group(request: pytest.FixtureRequest) -> str | None:
    """The group pytest-xdist distributes this test by, as its id names it."""
    if not os.environ.get("PYTEST_XDIST_WORKER") or not request.config.getvalue("loadgroup"):
        return None
    nodeid: str = request.node.nodeid
    return nodeid.partition("@")[2]


def test_a_test_of_a_module_fixture_is_in_its_modules_group(
        shared: str, request: pytest.FixtureRequest) -> None:
    assert shared
    marker = request.node.get_closest_marker("xdist_group")
    assert marker is not None and marker.kwargs["name"] == "tests/test_worker_groups.py"
    assert _group(request) in (None, "tests/test_worker_groups.py")


def test_a_test_without_one_is_in_none(request: pytest.FixtureRequest) -> None:
    assert request.node.get_closest_marker("xdist_group") is None
    assert _group(request) in (None, "")
