import subprocess
import sys
import tomllib

import pytest

from gateway.config import SCHEMA, default_config_text, load_config, validate
from gateway.errors import ConfigError


def test_default_text_is_complete_valid_toml_with_every_key_commented():
    text = default_config_text()
    data = tomllib.loads(text)
    cfg = validate(data, "<default>")
    for key in SCHEMA:
        assert data[key.section].get(key.name) == key.default
        assert getattr(getattr(cfg, key.section), key.name) == key.default
    # one comment line before each key; a key without a default is there as a commented example
    lines = text.splitlines()
    for key in SCHEMA:
        start = f"# {key.name} = " if key.default is None else f"{key.name} = "
        i = next(n for n, line in enumerate(lines) if line.startswith(start)
                 and f"[{key.section}]" in [head for head in lines[:n] if head.startswith("[")][-1:])
        assert lines[i - 1].startswith("# ")
        if key.default is None:
            assert tomllib.loads(lines[i][2:])[key.name] == key.example


def test_the_board_port_has_no_default_and_can_defaults_to_socketcan():
    cfg = validate({}, "<d>")
    assert cfg.serial.port is None
    assert (cfg.can.interface, cfg.can.channel) == ("socketcan", "can0")
    # an override keeps the unset port unset instead of failing on it
    assert cfg.replace({"modbus.port": 1502}).serial.port is None


@pytest.mark.parametrize(
    "toml, message",
    [
        ("[modbus]\nprot = 502\n", "unknown key modbus.prot"),
        ("[modbuss]\nport = 502\n", "unknown section [modbuss]"),
        ("[modbus]\nport = 70000\n", "modbus.port = 70000 must be ≤ 65535"),
        ("[modbus]\nport = \"502\"\n", "modbus.port = '502' must be a whole number"),
        ("[modbus]\nword_order = \"BADC\"\n", "modbus.word_order = 'BADC' must be one of 'ABCD', 'CDAB'"),
        ("[modbus]\nwrite_allow = [\"10.0.0.300\"]\n", "'10.0.0.300' is not an IP address or network"),
        ("[can]\nperiod_ms = 0\n", "can.period_ms = 0 must be ≥ 1"),
        ("[can]\nsync_to_updates = 1\n", "can.sync_to_updates = 1 must be true or false"),
        ("[can]\nperiod_ms = 10\nmin_interval_ms = 20\n", "can.min_interval_ms must not exceed can.period_ms"),
        ("[calibration]\nsensitivity_x = 0.0\n", "calibration.sensitivity_x = 0.0 must be > 0.0"),
        ("[serial]\nreconnect_min_s = 9.0\nreconnect_max_s = 1.0\n", "must not exceed serial.reconnect_max_s"),
        ("[serial]\nbatch_frames = 18\n", "serial.batch_frames = 18 must be ≤ 17"),
        # the ADXL202 data sheet's T2 range, 0.5-10 ms, at T2 = RSET / 125 MOhm
        ("[serial]\nemulated_rset_kohm = 2000.0\n", "serial.emulated_rset_kohm = 2000.0 must be ≤ 1250"),
        ("[serial\n", "not valid TOML"),
        ("[serial]\nport = \"\"\n", "serial.port = '' must not be empty"),
        ("[serial]\nstale_after_ms = 3000\nlost_after_ms = 2000\n",
         "serial.stale_after_ms must not exceed serial.lost_after_ms"),
        ("[modbus]\ntcp_enabled = false\n[can]\nenabled = false\n", "no output enabled"),
        ("a = " + "[" * 5000 + "]" * 5000 + "\n", "nested too deeply"),
        ("a = " + "{b = " * 5000 + "1" + "}" * 5000 + "\n", "nested too deeply"),
        ("# " + "x" * (1 << 20) + "\n", "larger than 1048576 bytes"),
    ],
)
def test_bad_config_names_the_key(tmp_path, toml, message):
    path = tmp_path / "gw.toml"
    path.write_text(toml)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert message in str(info.value)
    assert str(info.value).startswith(str(path))


def test_ints_are_accepted_for_floats_but_not_bools_for_ints(tmp_path):
    path = tmp_path / "gw.toml"
    path.write_text("[serial]\nreconnect_max_s = 3\n")
    assert load_config(path).serial.reconnect_max_s == 3.0
    path.write_text("[modbus]\nport = true\n")
    with pytest.raises(ConfigError, match="must be a whole number"):
        load_config(path)


def test_overrides_are_validated_too():
    cfg = validate({}, "<d>")
    assert cfg.replace({"modbus.port": 1502}).modbus.port == 1502
    with pytest.raises(ConfigError, match="modbus.port = -1"):
        cfg.replace({"modbus.port": -1})


def test_cli_config_default_and_check(tmp_path):
    r = subprocess.run([sys.executable, "-m", "gateway.cli", "config", "--default"], capture_output=True, text=True)
    assert r.returncode == 0
    path = tmp_path / "gw.toml"
    path.write_text(r.stdout)
    r = subprocess.run([sys.executable, "-m", "gateway.cli", "config", "--check", str(path)],
                       capture_output=True, text=True)
    # the default file does not run: the board's port is the one thing it cannot guess
    assert r.returncode == 2 and "modbus.port = 5020" in r.stdout
    assert f"adxlgw config: error: {path}: serial.port: not set" in r.stderr
    board = tmp_path / "ttyUSB0"  # what the check asks of a device path: that it exists
    board.touch()
    # (Modbus port 0: the check binds the port, and another gateway may hold 5020 here)
    path.write_text(f'[serial]\nport = "{board}"\n[modbus]\nport = 0\n[can]\ninterface = "virtual"\nchannel = "x"\n')
    r = subprocess.run([sys.executable, "-m", "gateway.cli", "config", "--check", str(path)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "can.channel: python-can's in-process virtual bus: no frame leaves this process" in r.stderr
    assert r.stderr.strip().endswith(f"{path}: ok")
    path.write_text("[can]\nchanel = \"vcan0\"\nperiod_ms = 0\n")
    r = subprocess.run([sys.executable, "-m", "gateway.cli", "config", "--check", str(path)],
                       capture_output=True, text=True)
    assert r.returncode == 2
    # every problem at once, one line each
    assert r.stderr.strip().splitlines() == [
        f"adxlgw config: error: {path}: unknown key can.chanel (did you mean can.channel?)",
        f"{path}: can.period_ms = 0 must be ≥ 1"]


def test_cli_regmap_json_and_dbc_match_the_shipped_files():
    import json
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    r = subprocess.run([sys.executable, "-m", "gateway.cli", "regmap", "--json"], capture_output=True, text=True)
    assert r.returncode == 0
    rows = json.loads(r.stdout)
    names = {row["name"]: row for row in rows}
    assert names["POSITION"]["address"] == 4 and names["POSITION"]["table"] == "input"
    r = subprocess.run([sys.executable, "-m", "gateway.cli", "dbc"], capture_output=True, text=True)
    assert r.returncode == 0
    assert r.stdout == (root / "config" / "adxl-gateway.dbc").read_text()


def test_a_file_that_is_not_utf8_is_named_with_the_byte_offset(tmp_path):
    path = tmp_path / "gw.toml"
    content = b'[serial]\nport = "/dev/tty\xffUSB0"\n'
    path.write_bytes(content)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"{path}: not UTF-8: byte 0xff at offset {content.index(0xFF)}"


@pytest.mark.parametrize("key, value, complaint", [
    ("max_connections", 0, "must be ≥ 1"),
    ("idle_timeout_s", -1.0, "must be ≥ 0"),
    ("peer_log_interval_s", 0.0, "must be ≥ 0.1"),
    ("priority_clients", ["plc.local"], "is not an IP address or network"),
    ("device_name", "x" * 33, "is longer than 32 characters"),
    ("device_name", "Zürich", "must be printable ASCII"),
])
def test_modbus_robustness_and_identity_keys_are_checked(key, value, complaint):
    with pytest.raises(ConfigError) as caught:
        validate({"modbus": {key: value}}, "gw.toml")
    assert str(caught.value).startswith(f"gw.toml: modbus.{key} = ") and complaint in str(caught.value)


def test_modbus_keys_reach_the_server_config():
    from gateway.daemon.settings import modbus_config_from

    cfg = validate({"modbus": {"max_connections": 8, "priority_clients": ["10.1.0.0/16"], "idle_timeout_s": 30,
                               "peer_log_interval_s": 2.5, "device_name": "press 4"}}, "gw.toml")
    server = modbus_config_from(cfg)
    assert (server.max_connections, server.priority_clients, server.idle_timeout_s, server.peer_log_interval_s,
            server.device_name) == (8, ("10.1.0.0/16",), 30.0, 2.5, "press 4")
