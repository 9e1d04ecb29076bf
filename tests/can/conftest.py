"""Fixtures of the CAN tests: a fresh virtual channel per test, and no channel left open."""
from __future__ import annotations

import itertools

import pytest
from can.interfaces import virtual

_channel_numbers = itertools.count()


@pytest.fixture(autouse=True)
def no_leaked_virtual_channels():
    """Like python-can's own conftest: every test must shut its buses down."""
    before = set(virtual.channels)
    yield
    leaked = set(virtual.channels) - before
    assert not leaked, f"virtual CAN channels left open: {leaked}"


@pytest.fixture
def channel(request) -> str:
    return f"adxl-{request.node.name}-{next(_channel_numbers)}"
