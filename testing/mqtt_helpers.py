"""A real mosquitto for the tests and the fleet benchmark: its own config in a temporary
folder, a free loopback port, started and stopped (or killed) like a service."""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Broker:
    """mosquitto on 127.0.0.1:`port`. `users`: {name: password} (anonymous refused then);
    `bridge_to`: another Broker whose every Sparkplug topic this one carries both ways;
    `persistence`: keep sessions and queued QoS 1 messages across a restart;
    `max_queued_messages`: per client while it is away (mosquitto's default 1000)."""

    def __init__(self, folder: Path, *, users: dict[str, str] | None = None, bridge_to: Broker | None = None,
                 persistence: bool = False, max_queued_messages: int | None = None, name: str = "broker"):
        self.folder = Path(folder) / name
        self.folder.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.proc: subprocess.Popen | None = None
        lines = [f"listener {self.port} 127.0.0.1", "log_dest stderr", "log_type error", "log_type warning"]
        if os.geteuid() == 0:
            lines.append("user root")  # else mosquitto drops to its own user, who cannot read this folder
        if users:
            passwords = self.folder / "passwords"
            passwords.touch()
            for user, password in users.items():
                subprocess.run(["mosquitto_passwd", "-b", str(passwords), user, password], check=True,
                               capture_output=True)
            lines += ["allow_anonymous false", f"password_file {passwords}"]
        else:
            lines.append("allow_anonymous true")
        if persistence:
            lines += ["persistence true", f"persistence_location {self.folder}/"]
        if max_queued_messages is not None:
            lines.append(f"max_queued_messages {max_queued_messages}")
        if bridge_to is not None:
            lines += [f"connection to-{bridge_to.folder.name}", f"address 127.0.0.1:{bridge_to.port}",
                      "topic spBv1.0/# both 1", "cleansession true", "restart_timeout 1 5",
                      f"remote_clientid bridge-{name}-{self.port}"]
        self.conf = self.folder / "mosquitto.conf"
        self.conf.write_text("\n".join(lines) + "\n")
        self.log = self.folder / "mosquitto.log"

    def start(self, timeout_s: float = 20.0) -> Broker:
        with open(self.log, "ab") as log:  # the child keeps its own copy of the descriptor
            self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.conf)], stdout=log, stderr=log)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"mosquitto exited: {self.log.read_text()[-2000:]}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=1):
                    return self
            except OSError:
                time.sleep(0.05)
        raise RuntimeError(f"mosquitto not listening on {self.port} within {timeout_s} s")

    def stop(self) -> None:
        """As a service manager stops it (SIGTERM: it saves its persistence file)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None

    def __enter__(self) -> Broker:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
