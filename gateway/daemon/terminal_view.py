"""A live terminal view of distance, velocity and status, apart from the log lines.

On a terminal the view is a rich `Live` region kept at the bottom of the screen, and
while it is shown the log lines go through the same console, so rich prints each one
above the region and redraws the region below it: log lines scroll, the view stays,
neither overwrites the other. Elsewhere (a pipe, a file, the journal) each draw is one
plain line. Use it as a context manager: it takes over the root logger's stream
handlers while shown and gives them back after.
"""
from __future__ import annotations

import logging
import math

from rich.console import Console
from rich.live import Live
from rich.text import Text

from drivers.published_values import PublishedValues, StatusBits, StatusExtBits


def _num(value: float, scale: float, fmt: str) -> str:
    return "   —   " if value is None or not math.isfinite(value) else format(value * scale, fmt)


def render(values: PublishedValues, extra: str = "") -> list[str]:
    flags = " ".join([b.name for b in StatusBits if b in values.status]
                     + [b.name for b in StatusExtBits if b in values.status_ext]) or "—"
    age = "—" if values.last_sample_age_ms is None else f"{values.last_sample_age_ms:.0f} ms"
    temp = "—" if values.board_temp_c is None else f"{values.board_temp_c:.1f} °C"
    return [
        f"position {_num(values.position_m, 1e3, '9.2f')} mm  ±{_num(values.position_std_m, 1e3, '.2f')}"
        f"   velocity {_num(values.velocity_mps, 1e3, '8.1f')} mm/s"
        f"   acceleration {_num(values.acceleration_mps2, 1, '7.2f')} m/s²",
        f"status   {flags}",
        f"samples {values.sample_counter}  age {age}  lost {values.lost_samples}  crc errors {values.crc_errors}"
        f"  resets {values.board_resets}  bias {_num(values.bias_estimate_mps2, 1e3, '.2f')} mm/s²  board {temp}",
        extra,
    ]


class _ConsoleLogHandler(logging.Handler):
    """Log records printed through the console that shows the live region."""

    def __init__(self, console: Console):
        super().__init__()
        self.console = console

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.console.print(Text(self.format(record)), soft_wrap=True)
        except Exception:  # noqa: BLE001 — logging's own rule: a failing handler must not raise
            self.handleError(record)


class TerminalView:
    def __init__(self, console: Console | None = None):
        self.console = console or Console(highlight=False)
        self.ansi = self.console.is_terminal
        self._live: Live | None = None
        self._handler: _ConsoleLogHandler | None = None
        self._moved: list[logging.Handler] = []

    def __enter__(self) -> TerminalView:
        if self.ansi:
            self._live = Live(console=self.console, auto_refresh=False)  # redrawn by draw(), no thread
            self._live.start()
            root = logging.getLogger()
            # the plain stream handlers (stderr): their lines would land inside the region
            self._moved = [h for h in root.handlers if type(h) is logging.StreamHandler]
            self._handler = _ConsoleLogHandler(self.console)
            if self._moved:
                self._handler.setFormatter(self._moved[0].formatter)
                self._handler.setLevel(self._moved[0].level)
            for handler in self._moved:
                root.removeHandler(handler)
            root.addHandler(self._handler)
        return self

    def __exit__(self, *exc) -> None:
        if self._live is not None:
            root = logging.getLogger()
            root.removeHandler(self._handler)
            for handler in self._moved:
                root.addHandler(handler)
            self._moved = []
            self._live.stop()  # the last drawing stays on the screen
            self._live = None

    def draw(self, values: PublishedValues, extra: str = "") -> None:
        lines = render(values, extra)
        if self._live is not None:
            self._live.update(Text("\n".join(lines)), refresh=True)
        else:
            self.console.file.write(" | ".join(line for line in lines if line) + "\n")
            self.console.file.flush()
