"""adxlgw emulate: a virtual board on a pseudo-terminal (or on a given serial port)."""
from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import signal
import sys
import threading
import time

import serial

from drivers.pty_port import PtyPort
from gateway.commands.common import (
    StopOnSignal,
    add_scenario_options,
    non_negative_float,
    positive_float,
    scenario_from_args,
)
from gateway.core.sensor_model import BOARD_SENSOR
from gateway.emulator import EmulatorSettings, FaultSettings, Pacer, board_schedule
from gateway.errors import DeviceError, InputError

log = logging.getLogger("adxlgw.emulate")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "emulate",
        help="virtual board: stream a simulated run on a pty and print its path",
        description="Create a pseudo-terminal (or write to --port), print the device path on the first "
                    "line of stdout, and stream the board's frames of a simulated run: HELLO first, "
                    "SAMPLE frames in real time (or as fast as the reader takes them with --fast), "
                    "STATUS once a second.",
    )
    add_scenario_options(p)
    p.add_argument("--port", help="write to this serial port or pyserial URL instead of creating a pty")
    p.add_argument("--link", help="also make this path a symlink to the pty (a stable name, like /dev/serial/by-id)")
    p.add_argument("--fast", action="store_true", help="do not pace: as fast as the line allows")
    p.add_argument("--loop", action="store_true", help="repeat the scenario forever (new noise each time)")
    p.add_argument("--no-wait", action="store_true",
                   help="start at once; by default the board powers on when a reader first opens the port, "
                        "so the reader sees the HELLO and every sample")
    p.add_argument("--exit-with-stdin", action="store_true",
                   help="stop when standard input reaches its end: a parent that holds the other end of a "
                        "pipe takes the board with it when it dies, even by SIGKILL")
    p.add_argument("--rset-kohm", type=rset_kohm, default=BOARD_SENSOR.rset_ohm / 1e3,
                   help="the ADXL202's RSET, kΩ: it sets the sensor period, T2 = RSET / 125 MΩ (data sheet: "
                        "0.5–10 ms, so 62.5–1250 kΩ); default: the board's 250 kΩ, 2 ms, 500 samples/s")
    p.add_argument("--linger", type=non_negative_float, default=1.0,
                   help="keep the port open this long after the last frame, s (default: 1)")
    f = p.add_argument_group("faults (each: period in seconds of board time; 0 = off)")
    f.add_argument("--garbage-every", type=non_negative_float, default=0.0, help="random bytes between frames")
    f.add_argument("--burst-every", type=non_negative_float, default=0.0, help="hold frames 50 ms, then send at once")
    f.add_argument("--reset-every", type=non_negative_float, default=0.0, help="board reset: HELLO, seq from 0")
    f.add_argument("--drop-every", type=non_negative_float, default=0.0, help="lose one sample on the line")
    f.add_argument("--reopen-every", type=non_negative_float, default=0.0,
                   help="the pty vanishes for 0.5 s and a new one appears (use with --link)")
    cut = p.add_argument_group("a line cut (once)")
    cut.add_argument("--cut-after", type=non_negative_float, default=0.0,
                     help="this long into the board's run, s, the line is cut for --cut-for seconds: nothing "
                          "arrives while the board's seq and clock run on, so the samples are lost (unlike a board "
                          "that stalls and then writes what it owes); 0: never (default)")
    cut.add_argument("--cut-for", type=positive_float,
                     help=f"how long the line stays cut, s (default: {FaultSettings.cut_for_s:g})")
    p.set_defaults(run=run)


class _SerialOut:
    def __init__(self, url: str):
        try:
            self.port = serial.serial_for_url(url, baudrate=115200, timeout=1, write_timeout=None)
        except (serial.SerialException, OSError, ValueError) as err:
            raise DeviceError(f"cannot open {url}: {err}") from err
        self.path = url

    def write(self, data: bytes, block: bool = True) -> int:
        return self.port.write(data)

    def has_reader(self) -> bool:
        return True  # a real line: the board cannot tell

    def wait_for_reader(self, timeout_s=None) -> bool:
        return True

    def close(self, remove_link: bool = False) -> None:
        self.port.close()


def _stop_at_end_of_stdin() -> None:
    """Block on stdin until its writer is gone (the parent closed it or died), then stop
    as SIGTERM would: the loop ends, the pty and its link are removed."""
    while os.read(sys.stdin.fileno(), 4096):
        pass
    os.kill(os.getpid(), signal.SIGTERM)


def rset_kohm(text: str) -> float:
    """--rset-kohm: within the data sheet's T2 range (0.5–10 ms at 125 MΩ per second)."""
    value = positive_float(text)
    if not 62.5 <= value <= 1250:
        raise argparse.ArgumentTypeError(f"{text}: RSET must be within 62.5–1250 kΩ (T2 0.5–10 ms, ADXL202 data sheet)")
    return value


def _settings(args: argparse.Namespace) -> EmulatorSettings:
    if args.cut_for is not None and not args.cut_after:
        raise InputError("--cut-for without --cut-after: the line is never cut")
    return EmulatorSettings(
        scenario=scenario_from_args(args),
        sensor=dataclasses.replace(BOARD_SENSOR, rset_ohm=args.rset_kohm * 1e3),
        seed=args.seed,
        loop=args.loop,
        faults=FaultSettings(
            garbage_every_s=args.garbage_every,
            burst_every_s=args.burst_every,
            reset_every_s=args.reset_every,
            reopen_every_s=args.reopen_every,
            drop_every_s=args.drop_every,
            cut_after_s=args.cut_after,
            cut_for_s=FaultSettings.cut_for_s if args.cut_for is None else args.cut_for,
        ),
    )


def _stop_switch(args: argparse.Namespace) -> StopOnSignal:
    stop = StopOnSignal()
    if args.exit_with_stdin:
        threading.Thread(target=_stop_at_end_of_stdin, daemon=True, name="stdin-watch").start()
        # a parent that led a terminal's session (the demo on a terminal) takes its process
        # group with it by SIGHUP when it dies: stop in order then too (the link removed)
        signal.signal(signal.SIGHUP, lambda _signum, frame: setattr(stop, "stop", True))
    return stop


class _Player:
    """Plays the board's schedule on a port, paced, with the faults that concern the port:
    a burst (50 ms of chunks held back, then sent at once) and a reopen (the pty closed
    and made again)."""

    def __init__(self, out: PtyPort | _SerialOut, args: argparse.Namespace, reopen_gap_s: float) -> None:
        self.out = out
        self._args = args
        self._reopen_gap_s = reopen_gap_s
        self._pacer = Pacer(args.fast)
        self._next_burst = args.burst_every or float("inf")
        self._next_reopen = args.reopen_every or float("inf")
        self._held: list[bytes] = []
        self._hold_until = -1.0
        self.sent = {"sample": 0, "status": 0, "hello": 0, "garbage": 0}
        self.overflow = 0  # writes cut short because the reader fell behind and the buffer was full
        self.unheard = 0  # chunks sent while nobody had the port open

    def play(self, chunk) -> None:
        if chunk.due_s >= self._next_reopen and isinstance(self.out, PtyPort):
            self._next_reopen += self._args.reopen_every
            self._reopen()
        if chunk.due_s >= self._next_burst:
            self._next_burst += self._args.burst_every
            self._hold_until = chunk.due_s + 0.05
        if chunk.due_s < self._hold_until:
            self._held.append(chunk.data)
        else:
            self._send(chunk)
        self.sent[chunk.kind] += 1

    def _reopen(self) -> None:
        self.out.close()
        log.info("port closed (fault: reopen); back in %.1f s", self._reopen_gap_s)
        time.sleep(self._reopen_gap_s)
        self.out = PtyPort(self._args.link)
        print(self.out.path, flush=True)

    def _send(self, chunk) -> None:
        self._pacer.wait_until(chunk.due_s)
        if self._held:
            chunk.data = b"".join(self._held) + chunk.data
            self._held.clear()
        if not self.out.has_reader():
            self.unheard += 1  # a real line with nobody listening: the bytes are gone
        elif self.out.write(chunk.data, block=self._args.fast) < len(chunk.data):
            self.overflow += 1

    def flush_held(self) -> None:
        if self._held:
            self.out.write(b"".join(self._held))

    def summary(self) -> str:
        return ("emulate: sent " + ", ".join(f"{v} {k}" for k, v in self.sent.items())
                + f"; {self.unheard} chunks sent with nobody listening; {self.overflow} writes cut short "
                "(reader behind)")


def run(args: argparse.Namespace) -> int:
    settings = _settings(args)
    if args.reopen_every and args.port:
        raise DeviceError("--reopen-every works on the emulator's own pty, not with --port")
    out = _SerialOut(args.port) if args.port else PtyPort(args.link)
    print(out.path, flush=True)
    stop = _stop_switch(args)
    if not args.no_wait:
        while not stop and not out.wait_for_reader(timeout_s=0.2):
            pass
    player = _Player(out, args, settings.faults.reopen_gap_s)
    try:
        for chunk in board_schedule(settings):
            if stop:
                break
            player.play(chunk)
        player.flush_held()
        if not stop:
            time.sleep(args.linger)
    except OSError as err:
        raise DeviceError(f"writing to {player.out.path} failed: {err.strerror or err}") from err
    finally:
        player.out.close(remove_link=True)
        print(player.summary(), file=sys.stderr)
    return 0
