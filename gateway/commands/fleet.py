"""adxlgw fleet: every Sparkplug B edge node on a broker, as a primary host sees it."""
from __future__ import annotations

import argparse
import json
import sys
import time

from gateway.errors import DeviceError, InputError

DEFAULT_PORT = 1883
CONNECT_WAIT_S = 5.0  # a broker on the plant's network answers well within this
REFRESH_S = 1.0


def broker_address(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":") if ":" in text and not text.endswith("]") else (text, "", "")
    if not sep:
        return text, DEFAULT_PORT
    try:
        number = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: the port {port!r} is not a number") from None
    if not host or not 1 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not HOST[:PORT] (port 1–65535)")
    return host.strip("[]"), number


def add_parser(sub) -> None:
    p = sub.add_parser("fleet", help="every gateway on an MQTT broker, live (Sparkplug B host view)",
                       description="Subscribe to spBv1.0/<group>/# on the broker and show every edge node: "
                                   "node, device, online or dead, position, velocity, status, last seen. "
                                   "Nodes heard without their birth are asked for a rebirth. A live table "
                                   "until Ctrl-C, or with --seconds the table once after that long; --json "
                                   "for scripts (after --seconds, default 3).")
    p.add_argument("--broker", type=broker_address, required=True, metavar="HOST[:PORT]",
                   help=f"the broker (port {DEFAULT_PORT} unless given)")
    p.add_argument("--group", default="+", help="only this Sparkplug group (default: every group)")
    p.add_argument("--seconds", type=float, default=None, help="listen this long, print once, exit")
    p.add_argument("--json", action="store_true", help="print the rows as JSON (after --seconds, default 3)")
    p.add_argument("--credentials", default=None, metavar="FILE", help="a file whose first line is user:password")
    p.add_argument("--tls-ca", default=None, metavar="FILE", help="connect with TLS, trusting this CA file")
    p.add_argument("--primary-host-id", default=None, metavar="ID",
                   help="be the Sparkplug 3.0 primary host ID: publish spBv1.0/STATE/ID (retained, online now, "
                        "offline as the will and at exit), which gateways with mqtt.primary_host_id = ID "
                        "wait for before their birth")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from drivers.sparkplug_host import FleetListener
    from gateway.config import sparkplug_id_problem
    from gateway.daemon.settings import read_credentials

    host, port = args.broker
    if args.seconds is not None and not args.seconds > 0:
        raise InputError(f"--seconds must be > 0, got {args.seconds}")
    username = password = None
    if args.credentials:
        username, password = read_credentials(args.credentials, f"--credentials {args.credentials}")
    if args.primary_host_id is not None:
        problem = sparkplug_id_problem(args.primary_host_id)
        if problem:
            raise InputError(f"--primary-host-id {args.primary_host_id!r}: {problem}")
    listener = FleetListener(host, port, group=args.group, username=username, password=password,
                             tls_ca_file=args.tls_ca, primary_host_id=args.primary_host_id)
    with listener:
        if not listener.connected.wait(CONNECT_WAIT_S):
            why = listener.connect_error or f"no answer within {CONNECT_WAIT_S:g} s"
            raise DeviceError(f"broker {host}:{port}: {why}")
        if args.json:
            time.sleep(args.seconds or 3.0)
            json.dump({"broker": f"{host}:{port}", "time_unix_s": time.time(),
                       "nodes": [r.as_dict() for r in listener.rows()]}, sys.stdout, indent=1)
            sys.stdout.write("\n")
            return 0
        if args.seconds is not None:
            time.sleep(args.seconds)
            _print_table(listener.rows(), sys.stdout)
            return 0
        return _live(listener)


def _live(listener) -> int:
    from rich.console import Console
    from rich.live import Live

    console = Console()
    with Live(_rich_table(listener.rows()), console=console, refresh_per_second=2) as live:
        while True:
            time.sleep(REFRESH_S)
            live.update(_rich_table(listener.rows()))


COLUMNS = ("group", "node", "device", "state", "position mm", "velocity mm/s", "status", "last seen", "births",
           "lost")


def _cells(row, now_s: float) -> tuple[str, ...]:
    def mm(x):
        return "—" if x is None else f"{x * 1000:.1f}"

    status = "—" if row.status is None else f"{'usable' if row.usable else 'NOT usable'} 0x{row.status:04x}"
    seen = "never" if row.last_seen_unix_s is None else f"{max(0.0, now_s - row.last_seen_unix_s):.1f} s ago"
    return (row.group, row.node, row.device or "—", "online" if row.online else "DEAD", mm(row.position_m),
            mm(row.velocity_mps), status, seen, str(row.births), str(row.lost))


def _print_table(rows, out) -> None:
    now = time.time()
    table = [COLUMNS] + [_cells(r, now) for r in rows]
    widths = [max(len(line[i]) for line in table) for i in range(len(COLUMNS))]
    for line in table:
        out.write("  ".join(cell.ljust(w) for cell, w in zip(line, widths, strict=False)).rstrip() + "\n")
    if not rows:
        out.write("(no Sparkplug B edge node heard)\n")


def _rich_table(rows):
    from rich.table import Table

    table = Table(title="Sparkplug B fleet")
    for name in COLUMNS:
        numeric = name in ("position mm", "velocity mm/s", "births", "lost")
        table.add_column(name, justify="right" if numeric else "left")
    now = time.time()
    for r in rows:
        table.add_row(*_cells(r, now), style=None if r.online else "red")
    return table
