"""Fixtures of the board-side tests: ptys made on demand and unplugged after the test."""
from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from tests.serial_helpers import Pty


@pytest.fixture
def make_pty() -> Iterator[Callable[[], Pty]]:
    made: list[Pty] = []

    def make() -> Pty:
        made.append(Pty())
        return made[-1]

    yield make
    for pty in made:
        pty.unplug()
