"""The files [mqtt] points to, checked before the daemon starts — by `adxlgw config
--check` and by `adxlgw run` alike (gateway/daemon/preflight.py): a credentials file
that is not username:password is a config error (exit 2), a TLS CA file that cannot be
used makes the broker's link unusable (exit 3); each is one line naming the key and the
file, and `run` says it before it serves anything."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

TEST_CA = Path(__file__).resolve().parents[1] / "tls" / "test-ca.pem"
CLI = [sys.executable, "-m", "gateway.cli"]


def config(tmp_path: Path, **mqtt: str) -> Path:
    keys = "".join(f'{k} = "{v}"\n' for k, v in mqtt.items())
    path = tmp_path / "gw.toml"
    # (Modbus port 0: the check binds the port, and another gateway may hold 5020 here)
    path.write_text(f'[serial]\nport = "emulated"\n[modbus]\nport = 0\n[can]\nenabled = false\n'
                    f'[state]\npath = "{tmp_path / "state.json"}"\n[mqtt]\nenabled = true\nport = 1\n{keys}')
    return path


def errors(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "error" in line]


def test_config_check_reads_the_credentials_and_the_tls_ca_file(tmp_path):
    credentials = tmp_path / "mqtt-credentials"
    credentials.write_text("gateway:secret\n")
    good = config(tmp_path, credentials_file=str(credentials), tls_ca_file=str(TEST_CA))
    r = subprocess.run([*CLI, "config", "--check", str(good)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr

    credentials.write_text("only-a-name\n")
    not_pem = tmp_path / "ca.pem"
    not_pem.write_text("not a certificate\n")
    bad = config(tmp_path, credentials_file=str(credentials), tls_ca_file=str(not_pem))
    r = subprocess.run([*CLI, "config", "--check", str(bad)], capture_output=True, text=True)
    assert r.returncode == 2
    assert errors(r.stderr) == [
        f"adxlgw config: error: {bad}: mqtt.credentials_file: {credentials}: the first line must be username:password",
        f"adxlgw config: error: {bad}: mqtt.tls_ca_file: {not_pem}: holds no CA certificate TLS can load "
        "(NO_CERTIFICATE_OR_CRL_FOUND)"]

    missing = config(tmp_path, credentials_file=str(tmp_path / "nowhere"), tls_ca_file=str(tmp_path / "none.pem"))
    r = subprocess.run([*CLI, "config", "--check", str(missing)], capture_output=True, text=True)
    assert r.returncode == 2
    found = errors(r.stderr)
    assert len(found) == 2 and "mqtt.credentials_file" in found[0] and "nowhere" in found[0]
    assert f"mqtt.tls_ca_file: {tmp_path / 'none.pem'}: cannot be read (No such file or directory)" in found[1]


@pytest.mark.parametrize(("key", "content", "exit_code"), [
    ("tls_ca_file", "not a certificate\n", 3),  # the link to the broker cannot be set up
    ("credentials_file", "no-colon\n", 2),  # the configuration is wrong
])
def test_run_refuses_a_bad_mqtt_file_before_it_serves(tmp_path, key, content, exit_code):
    bad_file = tmp_path / "the-file"
    bad_file.write_text(content)
    path = config(tmp_path, **{key: str(bad_file)})
    r = subprocess.run([*CLI, "run", "--config", str(path)], capture_output=True, text=True, timeout=120)
    assert r.returncode == exit_code, r.stderr
    assert len(errors(r.stderr)) == 1
    assert errors(r.stderr)[0].startswith(f"adxlgw run: error: {path}: mqtt.{key}: {bad_file}: ")
    assert "Modbus server started" not in r.stderr  # refused before anything was served
