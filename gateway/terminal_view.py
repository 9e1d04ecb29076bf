"""A live terminal view of distance, velocity and status (a few lines, redrawn in place)."""
from __future__ import annotations

import math
import sys
from typing import TextIO

from drivers.published_values import PublishedValues, StatusBits


def _num(value: float, scale: float, fmt: str) -> str:
    return "   —   " if value is None or not math.isfinite(value) else format(value * scale, fmt)


def render(values: PublishedValues, extra: str = "") -> list[str]:
    flags = " ".join(b.name for b in StatusBits if b in values.status) or "—"
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


class TerminalView:
    def __init__(self, out: TextIO = sys.stdout):
        self.out = out
        self.lines_drawn = 0
        self.ansi = out.isatty()

    def draw(self, values: PublishedValues, extra: str = "") -> None:
        lines = render(values, extra)
        if self.ansi:
            if self.lines_drawn:
                self.out.write(f"\x1b[{self.lines_drawn}F")  # back to the view's first line
            self.out.write("".join(f"\x1b[2K{line}\n" for line in lines))
            self.lines_drawn = len(lines)
        else:
            self.out.write(" | ".join(line for line in lines if line) + "\n")
        self.out.flush()
