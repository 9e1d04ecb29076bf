"""What `adxlgw run` refuses and `adxlgw config --check` reports: the checks that ask
the machine (port set and present, drift-model file, host, CAN interface)."""
import subprocess
import sys
import uuid

import pytest

from gateway.config import validate
from gateway.daemon.preflight import findings, refuse_unrunnable
from gateway.errors import ConfigError

CLI = [sys.executable, "-m", "gateway.cli"]


def config(tmp_path, **sections):
    board = tmp_path / "ttyUSB0"
    board.touch()
    # Modbus on port 0: the check binds the port, and another gateway may hold 5020 here
    data = {"serial": {"port": str(board)}, "can": {"interface": "virtual", "channel": "pf"},
            "modbus": {"port": 0}}
    for name, table in sections.items():
        data.setdefault(name, {}).update(table)
    return validate(data, "gw.toml")


def by_key(cfg) -> dict[str, tuple[str, str]]:
    return {f.key: (f.severity, f.text) for f in findings(cfg)}


def test_a_complete_config_has_nothing_but_the_virtual_bus_note(tmp_path):
    assert by_key(config(tmp_path)) == {
        "can.channel": ("note", "python-can's in-process virtual bus: no frame leaves this process")}


@pytest.mark.parametrize("sections, key, severity, text", [
    ({"estimator": {"drift_model": "/nonexistent/drift.json"}}, "estimator.drift_model", "error",
     "/nonexistent/drift.json: cannot read: No such file or directory"),
    ({"modbus": {"host": "not a host"}}, "modbus.host", "error", "'not a host' does not resolve"),
    # run would exit 3 at the bind: the check says so first (it used to pass)
    ({"modbus": {"host": "10.99.99.99"}}, "modbus.host", "error", "not an address of this machine"),
    ({"can": {"interface": "nosuchcan"}}, "can.interface", "error", "python-can has no interface 'nosuchcan'"),
    ({"can": {"interface": "socketcan", "channel": "lo"}}, "can.channel", "error",
     "network interface 'lo' is not a CAN interface"),
    ({"can": {"interface": "socketcan", "channel": "nocan" + uuid.uuid4().hex[:8]}}, "can.channel", "device",
     "no network interface 'nocan"),
    ({"can": {"interface": "pcan", "channel": "PCAN_USBBUS1"}}, "can.channel", "note",
     "channel 'PCAN_USBBUS1' of interface pcan is found only when opened"),
    ({"serial": {"port": "/dev/ttyNOSUCH9"}}, "serial.port", "device", "/dev/ttyNOSUCH9 does not exist"),
    ({"serial": {"port": "socket://10.0.0.9:4001"}}, "serial.port", "note", "is a pyserial URL"),
    ({"serial": {"port": "emulated"}}, "serial.port", "note", "every value is simulated"),
    ({"modbus": {"rtu_enabled": True, "rtu_port": "/dev/ttyNOSUCH8"}}, "modbus.rtu_port", "device",
     "/dev/ttyNOSUCH8 does not exist"),
])
def test_each_finding_names_its_key(tmp_path, sections, key, severity, text):
    got = by_key(config(tmp_path, **sections))
    assert got[key][0] == severity
    assert text in got[key][1]


def test_run_refuses_errors_and_starts_despite_a_missing_device(tmp_path):
    with pytest.raises(ConfigError, match=r"^gw.toml: modbus.host: 'not a host' does not resolve"):
        refuse_unrunnable(config(tmp_path, modbus={"host": "not a host"}))
    left = refuse_unrunnable(config(tmp_path, serial={"port": "/dev/ttyNOSUCH9"}))
    assert [f.severity for f in left if f.key == "serial.port"] == ["device"]


def test_a_taken_modbus_port_is_unusable_at_start_exit_3(tmp_path):
    import socket

    from gateway.errors import DeviceError

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        cfg = config(tmp_path, modbus={"port": taken.getsockname()[1]})
        assert by_key(cfg)["modbus.port"][0] == "unusable"
        with pytest.raises(DeviceError, match="already in use"):
            refuse_unrunnable(cfg)


def test_a_reload_is_checked_only_on_what_it_changes_and_refused_whole(tmp_path):
    from gateway.daemon.preflight import refuse_reload

    running = config(tmp_path, serial={"port": "/dev/ttyNOSUCH9"})
    # unchanged wires are not checked again (the running daemon holds them, or waits)
    refuse_reload(running, running.replace({"can.period_ms": 20}))
    board = config(tmp_path)
    with pytest.raises(ConfigError, match="serial.port: /dev/ttyNOSUCH7 does not exist"):
        refuse_reload(board, board.replace({"serial.port": "/dev/ttyNOSUCH7"}))


def test_a_reload_that_changes_the_emulated_boards_rset_is_refused(tmp_path):
    """The emulated board's RSET sets its sensor period when the board starts: a reload
    cannot change it, so it is refused whole (not applied halfway, not ignored)."""
    from gateway.daemon.preflight import refuse_reload

    running = config(tmp_path, serial={"port": "emulated"})
    refuse_reload(running, running.replace({"can.period_ms": 20}))
    with pytest.raises(ConfigError, match="serial.emulated_rset_kohm: read when the emulated board starts"):
        refuse_reload(running, running.replace({"serial.emulated_rset_kohm": 1250.0}))


def test_config_check_and_run_give_the_same_verdict(tmp_path):
    """One function for both: a file `config --check` passes, run starts with; one it fails, run refuses."""
    path = tmp_path / "gw.toml"
    board = tmp_path / "ttyUSB0"
    board.touch()
    path.write_text(f'[serial]\nport = "{board}"\n[modbus]\nhost = "10.99.99.99"\nport = 0\n'
                    f'[can]\nenabled = false\n[state]\npath = "{tmp_path / "state.json"}"\n')
    check = subprocess.run([*CLI, "config", "--check", str(path)], capture_output=True, text=True, timeout=60)
    run = subprocess.run([*CLI, "run", "--config", str(path)], capture_output=True, text=True, timeout=60)
    assert check.returncode == 2 and run.returncode == 2, (check.stderr, run.stderr)
    assert "not an address of this machine" in check.stderr and "not an address of this machine" in run.stderr


def test_run_without_a_port_refuses_in_one_line_naming_the_key(tmp_path):
    path = tmp_path / "gw.toml"
    path.write_text(subprocess.run([*CLI, "config", "--default"], capture_output=True, text=True).stdout)
    for args in ([], ["--config", str(path)]):
        r = subprocess.run([*CLI, "run", *args], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "serial.port: not set" in lines[0] and "Traceback" not in r.stderr


def test_config_check_reports_every_problem_and_exits_2(tmp_path):
    path = tmp_path / "gw.toml"
    path.write_text('[serial]\nport = "/dev/ttyNOSUCH9"\n[modbus]\nhost = "not a host"\n'
                    '[can]\ninterface = "nosuchcan"\n[estimator]\ndrift_model = "/nonexistent/d.json"\n')
    r = subprocess.run([*CLI, "config", "--check", str(path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    errors = [line for line in r.stderr.splitlines() if line.startswith("adxlgw config: error: ")]
    assert [e.split(": ")[3] for e in errors] == ["serial.port", "estimator.drift_model", "modbus.host",
                                                  "can.interface"]
    assert "Traceback" not in r.stderr and not r.stderr.rstrip().endswith(": ok")


@pytest.mark.parametrize("content, message", [
    (b'[serial]\nport = "\xfe"\n', "not UTF-8: byte 0xfe at offset 17"),
    (("a = " + "[" * 5000 + "]" * 5000).encode(), "nested too deeply"),
])
def test_hostile_files_are_one_line_exit_2_in_check_and_run(tmp_path, content, message):
    path = tmp_path / "gw.toml"
    path.write_bytes(content)
    for command in (["config", "--check"], ["run", "--config"]):
        r = subprocess.run([*CLI, *command, str(path)], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"adxlgw {command[0]}: error: {path}: "), r.stderr
        assert message in lines[0]
