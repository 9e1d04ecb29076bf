"""Real SocketCAN (vcan0) tests, run inside a qemu VM (tests/vmcan/harness.py).

The host kernel has no vcan, so these boot a Debian kernel under qemu and run
tests/inside_vm/ there. They need scripts/install-vm-deps.sh to have run; if
the VM cannot boot they fail with the reason, they do not skip: CI must
exercise the real CAN stack.
"""

import shutil
import xml.etree.ElementTree as ET

import pytest

from tests.vmcan.harness import (
    GUEST_OUT_DIR,
    REPO_ROOT,
    VmBootError,
    VmResult,
    VmSettings,
    VmSetupError,
    pytest_argv,
    run_in_can_vm,
)

pytestmark = pytest.mark.vm

INNER_TEST_FILE = "tests/inside_vm/test_socketcan_loopback.py"
INNER_REPORT_NAME = "socketcan-loopback.xml"
INNER_TIMEOUT_S = 180.0


@pytest.fixture(scope="module")
def inner_run() -> VmResult:
    """One VM boot running the inner SocketCAN tests; a VmError fails every test here."""
    return run_in_can_vm(
        pytest_argv("-q", "-rA", f"--junitxml={GUEST_OUT_DIR}/{INNER_REPORT_NAME}", INNER_TEST_FILE),
        cwd=REPO_ROOT,
        timeout_s=INNER_TIMEOUT_S,
    )


def _inner_outcomes(run: VmResult) -> dict[str, str]:
    """Map inner test name (with parameters) to passed/failed/error/skipped."""
    assert INNER_REPORT_NAME in run.out_files, f"inner pytest left no report; its output:\n{run.output}"
    outcomes = {}
    for case in ET.fromstring(run.out_files[INNER_REPORT_NAME]).iter("testcase"):
        problems = [child.tag for child in case if child.tag in ("failure", "error", "skipped")]
        outcomes[case.get("name")] = problems[0] if problems else "passed"
    return outcomes


def test_inner_pytest_run_succeeded(inner_run):
    assert inner_run.returncode == 0, f"inner pytest failed in the VM:\n{inner_run.output}"


def test_python_can_frames_cross_vcan0(inner_run):
    outcomes = _inner_outcomes(inner_run)
    cases = {name: outcome for name, outcome in outcomes.items() if name.startswith("test_python_can_frame")}
    assert len(cases) == 3, f"expected 3 parametrized python-can cases, got {outcomes}\n{inner_run.output}"
    assert set(cases.values()) == {"passed"}, f"{cases}\n{inner_run.output}"


def test_candump_sees_cansend_frame_on_vcan0(inner_run):
    outcomes = _inner_outcomes(inner_run)
    outcome = outcomes.get("test_candump_captures_frame_sent_by_cansend")
    assert outcome == "passed", f"{outcomes}\n{inner_run.output}"


def test_vm_returns_exit_status_output_and_files():
    run = run_in_can_vm(
        ["sh", "-c", 'echo to-stdout; echo to-stderr >&2; echo kept > "$ADXLGW_VM_OUT_DIR/note.txt"; exit 7'],
        cwd=REPO_ROOT,
        timeout_s=60.0,
    )
    assert run.returncode == 7
    assert run.output.splitlines() == ["to-stdout", "to-stderr"]
    assert run.out_files == {"note.txt": b"kept\n"}


def test_missing_guest_kernel_names_the_install_script(tmp_path):
    with pytest.raises(VmSetupError, match="install-vm-deps.sh"):
        run_in_can_vm(["true"], cwd=REPO_ROOT, settings=VmSettings(cache_dir=tmp_path))


def test_guest_kernel_panic_is_reported(tmp_path):
    # A kernel with an initramfs that has no /init panics ("No working init
    # found" / "Unable to mount root fs"); the harness must say so, not hang.
    shutil.copy(VmSettings().cache_dir / "vmlinuz", tmp_path / "vmlinuz")
    (tmp_path / "initramfs.cpio.gz").write_bytes(b"")
    with pytest.raises(VmBootError, match="kernel panic"):
        run_in_can_vm(["true"], cwd=REPO_ROOT, timeout_s=60.0, settings=VmSettings(cache_dir=tmp_path))


def test_gateway_daemon_on_real_socketcan():
    """The daemon on vcan0 inside the VM; its traffic decoded by candump | cantools."""
    report = "gateway-vcan.xml"
    run = run_in_can_vm(
        pytest_argv("-q", "-rA", f"--junitxml={GUEST_OUT_DIR}/{report}", "tests/inside_vm/test_gateway_on_vcan.py"),
        cwd=REPO_ROOT,
        timeout_s=600.0,  # the inner waits: 240 s for a first valid frame, 60 s candump, 120 s the ack
    )
    assert run.returncode == 0, f"inner pytest failed in the VM:\n{run.output}"
    assert report in run.out_files and b'failures="0"' in run.out_files[report], run.output
    assert b'tests="1"' in run.out_files[report], run.output
