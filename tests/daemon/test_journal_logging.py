"""Log priorities the journal understands: sd-daemon "<N>" prefixes when stderr is the
stream systemd named in JOURNAL_STREAM, plain lines otherwise (gateway/log_setup.py)."""
import io
import logging
import os
import subprocess
import sys
from pathlib import Path

from gateway.log_setup import PLAIN_FORMAT, JournalFormatter, stream_is_journal

CLI = [sys.executable, "-m", "gateway.cli"]


def journal_env(path) -> dict:
    st = os.stat(path)
    return {**os.environ, "JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}


def test_every_line_of_a_record_carries_its_priority():
    out = io.StringIO()
    handler = logging.StreamHandler(out)
    handler.setFormatter(JournalFormatter(PLAIN_FORMAT))
    logger = logging.getLogger("test.journal")
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    logger.propagate = False
    try:
        logger.debug("d")
        logger.info("i")
        logger.warning("w")
        logger.error("two\nlines")
        logger.critical("c")
    finally:
        logger.removeHandler(handler)
    assert out.getvalue().splitlines() == [
        "<7>DEBUG test.journal: d", "<6>INFO test.journal: i", "<4>WARNING test.journal: w",
        "<3>ERROR test.journal: two", "<3>lines", "<2>CRITICAL test.journal: c"]


def test_only_the_stream_systemd_named_is_the_journal(tmp_path):
    named, other = tmp_path / "journal", tmp_path / "other"
    with open(named, "w") as a, open(other, "w") as b:
        env = journal_env(named)
        assert stream_is_journal(a, env)
        assert not stream_is_journal(b, env)  # a child's redirected stderr inherits the variable
        assert not stream_is_journal(a, {})
        assert not stream_is_journal(a, {"JOURNAL_STREAM": "garbage"})
        assert not stream_is_journal(io.StringIO(), env)


def test_the_command_line_prefixes_errors_and_warnings_for_the_journal(tmp_path):
    """A config error (exit 2) and the numba warning, as `journalctl -p` sorts them."""
    bad = tmp_path / "gw.toml"
    bad.write_text("[modbus]\nprot = 1\n")
    log = tmp_path / "stderr"
    with open(log, "w") as stderr:
        env = {**journal_env(log), "ADXLGW_NO_JIT": ""}
        r = subprocess.run([*CLI, "config", "--check", str(bad)], stderr=stderr, stdout=subprocess.DEVNULL,
                           env=env, timeout=60)
    assert r.returncode == 2
    unknown = "unknown key modbus.prot (did you mean modbus.port?)"
    assert log.read_text().splitlines() == [f"<3>adxlgw config: error: {bad}: {unknown}"]
    fake = tmp_path / "site" / "numba"  # numba that cannot start: one warning, priority 4
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text('raise PermissionError("cannot allocate executable memory")\n')
    env["PYTHONPATH"] = os.pathsep.join([str(fake.parent), str(Path(__file__).resolve().parents[2])])
    with open(log, "w") as stderr:
        r = subprocess.run([*CLI, "config", "--default"], stderr=stderr, stdout=subprocess.DEVNULL, env=env,
                           timeout=60)
    assert r.returncode == 0
    lines = log.read_text().splitlines()
    assert len(lines) == 1 and lines[0].startswith("<4>WARNING adxlgw: numba cannot start: PermissionError")


def test_off_the_journal_lines_are_plain(tmp_path):
    bad = tmp_path / "gw.toml"
    bad.write_text("[modbus]\nprot = 1\n")
    r = subprocess.run([*CLI, "config", "--check", str(bad)], capture_output=True, text=True, timeout=60,
                       env={**os.environ, "JOURNAL_STREAM": "1:1"})
    unknown = "unknown key modbus.prot (did you mean modbus.port?)"
    assert r.stderr.splitlines() == [f"adxlgw config: error: {bad}: {unknown}"]
