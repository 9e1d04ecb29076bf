"""Any bytes a user can write as a config: a Config or one ConfigError line, nothing else
(issue 16). Random files and the default config mutated byte by byte."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import default_config_text, load_config
from gateway.errors import ConfigError

DEFAULT = default_config_text().encode()
REPO = Path(__file__).resolve().parents[2]


@st.composite
def mutated_defaults(draw) -> bytes:
    data = bytearray(DEFAULT)
    for _ in range(draw(st.integers(1, 6))):
        kind = draw(st.sampled_from(["flip", "cut", "insert", "delete"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if kind == "flip" and data:
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif kind == "cut":
            del data[at:]
        elif kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=12))
        elif data:
            del data[at:at + draw(st.integers(1, 40))]
    return bytes(data)


def check(tmp_path_factory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("cfg") / "gw.toml"
    path.write_bytes(data)
    try:
        load_config(path)
    except ConfigError as err:
        # every problem at once: each line names the file and what is wrong
        lines = str(err).split("\n")
        assert all(line and str(path) in line for line in lines), str(err)


@settings(max_examples=300)
@given(data=mutated_defaults())
def test_a_mutated_default_config_loads_or_is_one_config_error_a_line_per_problem(tmp_path_factory, data):
    check(tmp_path_factory, data)


@settings(max_examples=150)
@given(data=st.one_of(st.binary(max_size=300), st.text(max_size=300).map(str.encode)))
def test_random_bytes_load_or_are_one_config_error(tmp_path_factory, data):
    check(tmp_path_factory, data)


def test_the_command_line_says_it_in_one_line_and_exits_2(tmp_path):
    """Through `adxlgw config --check` as a user runs it: exit 2, one line on stderr."""
    samples = [DEFAULT.replace(b"[serial]", b"[serial", 1), DEFAULT[:len(DEFAULT) // 3] + b"\xff\xfe",
               b"a = [" * 5000, b"[modbus]\nport = 99999\n"]
    for k, data in enumerate(samples):
        path = tmp_path / f"bad{k}.toml"
        path.write_bytes(data)
        r = subprocess.run([sys.executable, "-m", "gateway.cli", "config", "--check", str(path)],
                           capture_output=True, text=True, timeout=120, cwd=REPO)
        lines = [line for line in r.stderr.splitlines() if line.strip()]
        assert r.returncode == 2 and lines and all("Traceback" not in line for line in lines), r.stderr
        assert all(str(path) in line or "adxlgw" in line for line in lines), r.stderr
