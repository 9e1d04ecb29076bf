"""The shipped unit under a real systemd as PID 1 (issue 15), inside the qemu VM.

tests/inside_vm/systemd_job.sh installs the unit with `adxlgw install-files --root /`
into the VM's RAM overlay, adds the VM-only drop-ins it explains (a pty board, Python
under /root, and for the emulated CPU: no numba, longer start/stop/watchdog timeouts),
and boots systemd as PID 1 of its own PID and mount namespaces. A driver service
(tests/inside_vm/systemd_driver.py) runs systemctl, journalctl, systemd-analyze and a
Modbus client there and writes a JSON report; the tests here judge it. One VM boot for
all of them (module fixture). Like every `vm` test this fails, never skips, when the VM
cannot boot. Measured numbers are printed (pytest -s or -rA shows them) and recorded in
docs/daemon.md; the bounds here are generous for an emulated CPU on a loaded machine.
"""
from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

from gateway.daemon.status_flags import EVENT_HOLD_S
from tests.vmcan.harness import REPO_ROOT, VmResult, VmSettings, default_guest_env, run_in_can_vm

pytestmark = [pytest.mark.vm, pytest.mark.slow]

REPORT = "systemd-report.json"
# the whole VM run: 5-7 min measured here under load (docs/daemon.md); the harness kills it after this
VM_TIMEOUT_S = 1500.0
START_TIMEOUT_S = 600  # the VM drop-in's TimeoutStartSec (emulated CPU: cold imports)
WATCHDOG_S = 30  # the VM drop-in's WatchdogSec
STOP_TIMEOUT_S = 30  # the VM drop-in's TimeoutStopSec; the stop must end well inside it, not by SIGKILL
STOP_BOUND_S = 15.0  # what the test accepts under emulation (the unit's 2 s is for a real CPU)


def run_systemd_job() -> VmResult:
    adxlgw = Path(sys.executable).parent / "adxlgw"
    env = {**default_guest_env(), "ADXLGW_VM_START_TIMEOUT_SEC": str(START_TIMEOUT_S),
           "ADXLGW_VM_WATCHDOG_SEC": str(WATCHDOG_S), "ADXLGW_VM_STOP_TIMEOUT_SEC": str(STOP_TIMEOUT_S),
           "ADXLGW_VM_JOB_LIMIT_S": str(int(VM_TIMEOUT_S) - 60)}
    return run_in_can_vm(["/bin/sh", "tests/inside_vm/systemd_job.sh", str(adxlgw)], cwd=REPO_ROOT,
                         timeout_s=VM_TIMEOUT_S, env=env, settings=VmSettings(cpu_count=2, memory_mib=1536))


# The unit runs with DynamicUser, which implies a private /tmp: a venv in a checkout under
# /tmp or /var/tmp cannot be executed by it (tried: 203/EXEC, and a bind mount from /tmp
# fails with 226/NAMESPACE). Said at once instead of nine failures after a 5-minute VM run.
HIDDEN_FROM_THE_UNIT = ("/tmp/", "/var/tmp/")


@pytest.fixture(scope="module")
def vm_run() -> VmResult:
    if str(REPO_ROOT).startswith(HIDDEN_FROM_THE_UNIT):
        pytest.fail(f"the checkout {REPO_ROOT} is under /tmp or /var/tmp, which the unit's DynamicUser hides "
                    "(a private /tmp): clone it elsewhere to run the systemd VM test")
    return run_systemd_job()


@pytest.fixture(scope="module")
def report(vm_run) -> dict:
    assert vm_run.returncode == 0, f"the systemd job failed in the VM:\n{vm_run.output}"
    assert REPORT in vm_run.out_files, f"no report from the driver:\n{vm_run.output}"
    data = json.loads(vm_run.out_files[REPORT])
    print(f"\nsystemd in the VM: {summary(data)}; whole VM run {vm_run.total_s:.0f} s")
    return data


def summary(report: dict) -> str:
    """The numbers docs/daemon.md records, as one line."""
    sb = report.get("silent_board", {})
    return (f"READY after {report.get('start', {}).get('seconds')} s, "
            f"stop {report.get('stop', {}).get('seconds')} s ({report.get('stop', {}).get('Result')}), "
            f"silent board restarted after {sb.get('seconds')} s and active again after {sb.get('back_after_s')} s, "
            f"security: {security_line(report) or 'missing'}")


def security_line(report: dict) -> str | None:
    match = re.search(r"Overall exposure level for \S+: ([0-9.]+) (\S+)",
                      report.get("security", {}).get("stdout", ""))
    return f"{match.group(1)} {match.group(2)}" if match else None


def test_driver_ran_to_the_end(report, vm_run):
    # what the daemon logged last says why the driver stopped (a closed connection, a timeout);
    # PID 1's lines about the unit (a watchdog timeout, an exit, a restart: systemd logs to
    # the kernel ring here, not to the journal) and the daemon's errors say whether the
    # gateway was restarted under the driver
    lines = report.get("journal", "").splitlines()
    journal_tail = "\n".join(lines[-30:])
    errors = "\n".join([line for line in lines if " ERROR " in line or "Traceback" in line][-20:])
    pid1 = [line for line in vm_run.out_files.get("pid1.log", b"").decode().splitlines() if "adxl-gateway" in line]
    pid1_on_unit = "\n".join(pid1[-20:])
    assert "driver_error" not in report, (f"{report['driver_error']}\nPID 1 on the unit:\n{pid1_on_unit}\n"
                                          f"the daemon's errors:\n{errors}\n"
                                          f"the unit's journal, last lines:\n{journal_tail}")


def start_failure(report: dict, vm_run: VmResult) -> str:
    """Why the unit did not start: systemd's result and exit status (e.g. 238/STATE_DIRECTORY),
    the unit's journal, and PID 1's log."""
    start = report["start"]
    pid1 = vm_run.out_files.get("pid1.log", b"").decode()
    return (f"systemctl start: {start.get('stderr', '').strip()}\n"
            f"Result={start.get('Result')} ExecMainCode={start.get('ExecMainCode')} "
            f"ExecMainStatus={start.get('ExecMainStatus')}\n"
            f"--- the unit's journal ---\n{start.get('journal', '')[-3000:]}\n--- PID 1 ---\n{pid1[-3000:]}")


def test_ready_within_the_start_timeout(report, vm_run):
    start = report["start"]
    assert start["rc"] == 0, start_failure(report, vm_run)
    assert (start["ActiveState"], start["SubState"]) == ("active", "running"), start
    assert start["seconds"] < START_TIMEOUT_S, start
    assert "board " in start["StatusText"] and "modbus 127.0.0.1:5020" in start["StatusText"], start
    # the drop-ins are in effect: what the numbers below were measured with
    assert "ADXLGW_NO_JIT=1" in start["Environment"], start


def test_watchdog_pings_advance_while_samples_flow(report):
    pings = report["watchdog_pings"]
    assert pings["watchdog_s"] == WATCHDOG_S, pings
    assert pings["first_us"] > 0, f"no WATCHDOG=1 within {2 * WATCHDOG_S} s of READY: {pings}"
    assert pings["later_us"] > pings["first_us"], pings
    assert pings["restarts"] == 0 and pings["active"] == "active", pings


def test_reload_keeps_the_modbus_connection(report):
    reload = report["reload"]
    assert reload["rc"] == 0, reload
    assert reload["logged"], f"no 'config reloaded' within 120 s of systemctl reload: {reload}"
    # the reads after the reload went over the same TCP connection (the driver's client
    # never reconnects: a dropped connection is a driver_error)
    seen = {k: reload.get(k) for k in ("same_connection", "config_reloaded_bit", "status_after",
                                       "bit_seen_after_s", "logged_after_s", "reads", "slowest_read_s",
                                       "dropped_watchers")}
    assert reload["same_connection"], seen
    # CONFIG_RELOADED is an event held EVENT_HOLD_S after the reload (the native reload tests
    # check it read for read). Polled here under emulation it is seen unless the reads
    # themselves took longer than the hold (a read that waits out the hold cannot see it):
    # then the VM cannot tell, and the report says so.
    assert reload["config_reloaded_bit"] or reload["slowest_read_s"] >= EVENT_HOLD_S, seen
    if not reload["config_reloaded_bit"]:
        print(f"\nCONFIG_RELOADED not observable under emulation: a read took {reload['slowest_read_s']} s "
              f"(hold {EVENT_HOLD_S} s)")
    assert reload["restarts"] == 0 and reload["main_pid"] == int(report["start"]["MainPID"]), reload


def test_a_bad_file_is_refused_on_reload_and_the_gateway_keeps_serving(report):
    bad = report["bad_reload"]
    assert bad["logged"], f"no 'reload refused' within 120 s: {bad}"
    assert bad["still_serving"] and bad["reloads_applied"] == 1, bad
    assert bad["restarts"] == 0 and bad["main_pid"] == int(report["start"]["MainPID"]), bad
    errors = [line for line in report["journal_err"].splitlines() if line.strip()]
    assert len(errors) == 1 and "reload refused" in errors[0], report["journal_err"]


def test_stop_ends_with_sigterm_in_bounded_time(report):
    stop = report["stop"]
    print(f"\nsystemctl stop under emulation: {stop['seconds']} s")
    assert stop["rc"] == 0, stop
    assert (stop["ActiveState"], stop["Result"]) == ("inactive", "success"), stop  # "timeout" = SIGKILL
    assert stop["seconds"] < STOP_BOUND_S, stop
    assert "stopped" in report["journal"], report["journal"][-3000:]


def test_state_is_persisted_under_the_state_directory(report):
    state = report["state"]
    assert state["exists"], state
    # DynamicUser=yes: systemd keeps the directory under /var/lib/private
    assert state["resolved"] == "/var/lib/private/adxl-gateway/state.json", state
    assert state["content"]["version"] == 1, state


def test_silent_board_is_restarted_by_the_watchdog(report, vm_run):
    silent = report["silent_board"]
    assert silent["board_pid"], f"no emulated-board child of {silent['main_pid']}: {silent}"
    assert silent["pinging_before"], silent
    assert silent["restarted"], f"no restart within {4 * WATCHDOG_S} s of SIGSTOP: {silent}"
    assert silent["seconds"] >= WATCHDOG_S * 0.5, silent  # the watchdog's doing, not a crash at once
    # PID 1 logs to the kernel ring buffer here (--log-target=kmsg); the job saves its lines
    pid1 = vm_run.out_files.get("pid1.log", b"").decode()
    assert "adxl-gateway.service: Watchdog timeout" in pid1, pid1[-3000:]
    assert silent["back_after_s"] is not None and silent["ActiveState"] == "active", silent
    assert int(silent["MainPID"]) != silent["main_pid"], silent
    assert silent["pinging_after"], silent  # the new board's samples feed the watchdog again


def test_security_score_is_reported(report):
    line = security_line(report)
    print(f"\nsystemd-analyze security adxl-gateway (with the VM drop-ins): {line}")
    assert line is not None, report["security"]
    assert float(line.split()[0]) <= 3.0, line  # 2.1-2.3 measured; a lost hardening line shows here
