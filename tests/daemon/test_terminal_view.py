"""The live view and the log lines in separate areas of the screen: what rich writes,
played on a terminal emulator (pyte), must show every log line above the view and the
view whole below them."""
import io
import logging

import pyte
from rich.console import Console

from drivers.published_values import PublishedValues, StatusBits
from gateway.daemon.terminal_view import TerminalView, render

WIDTH, HEIGHT = 120, 24


def screen_after(play) -> list[str]:
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=WIDTH, height=HEIGHT, color_system=None,
                      highlight=False)
    play(console)
    screen = pyte.Screen(WIDTH, HEIGHT)
    stream = pyte.Stream(screen)
    stream.feed(out.getvalue().replace("\n", "\r\n"))  # the tty's onlcr: a newline returns the carriage
    return [line.rstrip() for line in screen.display if line.strip()]


def values(position_mm: float) -> PublishedValues:
    return PublishedValues(position_m=position_mm / 1e3, velocity_mps=0.0, acceleration_mps2=0.0,
                           status=StatusBits.VALID, sample_counter=int(position_mm))


def test_log_lines_scroll_above_the_view_and_never_into_it():
    root = logging.getLogger()
    before = list(root.handlers)
    stderr_handler = logging.StreamHandler(io.StringIO())  # stands in for the CLI's stderr handler
    stderr_handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root.addHandler(stderr_handler)
    log = logging.getLogger("adxlgw.test")
    old_level = root.level
    root.setLevel(logging.INFO)
    try:
        def play(console):
            with TerminalView(console) as view:
                view.draw(values(1.0), "board /dev/pts/9")
                log.warning("first log line")
                view.draw(values(2.0), "board /dev/pts/9")
                for n in range(3):
                    log.error("line %d of several", n)
                view.draw(values(3.0), "board /dev/pts/9")
            assert stderr_handler in root.handlers  # given back afterwards

        shown = screen_after(play)
        assert stderr_handler.stream.getvalue() == ""  # nothing went around the view to stderr
    finally:
        root.handlers[:] = before
        root.setLevel(old_level)
    view_lines = [line.rstrip() for line in render(values(3.0), "board /dev/pts/9")]
    assert shown == ["WARNING adxlgw.test: first log line",
                     "ERROR adxlgw.test: line 0 of several",
                     "ERROR adxlgw.test: line 1 of several",
                     "ERROR adxlgw.test: line 2 of several",
                     *view_lines]


def test_off_a_terminal_each_draw_is_one_plain_line():
    out = io.StringIO()
    with TerminalView(Console(file=out, force_terminal=False)) as view:
        view.draw(values(1.0), "x")
        view.draw(values(2.0), "x")
    lines = out.getvalue().splitlines()
    assert len(lines) == 2 and "\x1b" not in out.getvalue()
    assert lines[1] == " | ".join(line for line in render(values(2.0), "x") if line)


def test_the_view_says_when_the_numbers_are_a_simulation():
    from drivers.published_values import PublishedValues, StatusBits, StatusExtBits
    from gateway.daemon.terminal_view import render

    lines = render(PublishedValues(status=StatusBits.VALID, status_ext=StatusExtBits.SIMULATED))
    assert "VALID" in lines[1] and "SIMULATED" in lines[1]
