"""What the wire tests (Modbus, CAN) share: a coroutine run with a time limit, and a
command handler that records what it was asked."""
from __future__ import annotations

import asyncio

from drivers.published_values import Command


def run(coro, timeout_s: float = 30.0):
    return asyncio.run(asyncio.wait_for(coro, timeout_s))


class Recorder:
    def __init__(self, answer: bool | Exception = True) -> None:
        self.calls: list[tuple[Command, str]] = []
        self.answer = answer

    def __call__(self, command: Command, source: str) -> bool:
        self.calls.append((command, source))
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer
