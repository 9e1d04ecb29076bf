"""Run a command inside a throw-away qemu VM that has a real SocketCAN bus (vcan0).

Why a VM: the host kernel has no vcan module and we cannot load modules, so
the real SocketCAN path (python-can's socketcan interface, can-utils) cannot
be exercised on the host. scripts/install-vm-deps.sh caches a stock Debian
kernel and a small initramfs in .cache/vm/; this module boots them under qemu
(software emulation, no KVM) with the host's root file system shared
read-only over 9p. The guest's /init loads can, can-raw, can-bcm and vcan,
brings up lo and vcan0, and chroots into a copy-on-write overlay of the host
root (writes land in guest RAM, never on the host), so the command runs with
the host's own Python, venv and repository at the same paths.

The job travels through a second, writable 9p share (a host temp dir):
job.sh in; output, exit status and the guest uptime at job start out.

See docs/socketcan-vm.md.
"""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
INSTALL_SCRIPT = "scripts/install-vm-deps.sh"
QEMU_BINARY = "qemu-system-x86_64"

# Console marker lines written by the guest's /init (see INSTALL_SCRIPT).
_READY_MARKER = "VMCAN-READY"
_INIT_FAILED_MARKER = "VMCAN-INIT-FAILED:"
_PANIC_MARKER = "Kernel panic"

# Set in the job's environment so tests/inside_vm/ knows it runs in the VM.
IN_VM_ENV_VAR = "ADXLGW_IN_VM"
# A guest directory whose files come back in VmResult.out_files (e.g. a
# --junitxml report); its path is in the job's environment under this name.
OUT_DIR_ENV_VAR = "ADXLGW_VM_OUT_DIR"
GUEST_OUT_DIR = "/run/vmjob/out"

_POLL_INTERVAL_S = 0.05
_CONSOLE_TAIL_CHARS = 3000


class VmError(RuntimeError):
    """The VM could not run the job; the message says why and what to do."""


class VmSetupError(VmError):
    """qemu, the guest kernel or the initramfs is missing."""


class VmBootError(VmError):
    """The guest did not get as far as running the job (timeout, panic, init failure)."""


class VmJobTimeoutError(VmError):
    """The job started but did not finish within the time limit."""


@dataclass(frozen=True)
class VmSettings:
    """How the VM is booted. Defaults suit a 2-core machine without KVM."""

    cache_dir: Path = Path(os.environ.get("ADXLGW_VM_DIR", REPO_ROOT / ".cache" / "vm"))
    memory_mib: int = 1024
    cpu_count: int = 1
    # Boot takes ~2-3 s idle on this machine; generous for a loaded CI host.
    boot_timeout_s: float = 60.0


@dataclass(frozen=True)
class VmResult:
    returncode: int
    output: str  # the job's stdout and stderr, interleaved
    console: str = field(repr=False)  # the guest's serial console (kernel messages, /init markers)
    boot_s: float  # host time from starting qemu to the guest reporting ready
    total_s: float  # host time from starting qemu to qemu exiting
    guest_uptime_at_job_start_s: float | None  # guest /proc/uptime just before the job
    out_files: dict[str, bytes] = field(repr=False)  # files the job left in $ADXLGW_VM_OUT_DIR, by name


def default_guest_env() -> dict[str, str]:
    """The host's environment, adjusted for a guest whose root is a RAM overlay."""
    env = dict(os.environ)
    env.pop("PYTEST_CURRENT_TEST", None)
    # Writes go to guest RAM and vanish with the VM: .pyc files would only
    # cost time, and the host's home is not the place for guest caches.
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def pytest_argv(*args: str, hypothesis_plugin: bool = False) -> list[str]:
    """argv for running pytest inside the VM with the host's interpreter.

    The cache provider is off because its cache would be lost with the VM.
    Hypothesis's pytest plugin is off unless asked for: at session end it
    imports all of hypothesis, which pytest then assertion-rewrites (a plugin
    distribution's modules are rewritten, and with no writable bytecode cache
    that is redone every run); under emulation that costs ~9 s per pytest run
    on this machine. @given tests work without the plugin; it only adds the
    --hypothesis-* options and statistics.
    """
    plugin_args = [] if hypothesis_plugin else ["-p", "no:hypothesispytest"]
    return [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", *plugin_args, *args]


def check_vm_available(settings: VmSettings = VmSettings()) -> tuple[Path, Path, str]:
    """Return (vmlinuz, initramfs, qemu path) or raise VmSetupError saying what to run."""
    qemu = shutil.which(QEMU_BINARY)
    if qemu is None:
        raise VmSetupError(
            f"{QEMU_BINARY} not found on PATH: run `sudo bash {INSTALL_SCRIPT}` "
            "(installs qemu-system-x86 and the guest kernel)"
        )
    kernel = settings.cache_dir / "vmlinuz"
    initramfs = settings.cache_dir / "initramfs.cpio.gz"
    for path in (kernel, initramfs):
        if not path.is_file():
            raise VmSetupError(
                f"guest kernel file {path} missing: run `sudo bash {INSTALL_SCRIPT}` "
                "(downloads a Debian kernel and builds the initramfs into .cache/vm/)"
            )
    return kernel, initramfs, qemu


def _job_script(argv: list[str], cwd: str, env: dict[str, str]) -> str:
    job_env = dict(env)
    job_env[IN_VM_ENV_VAR] = "1"
    job_env[OUT_DIR_ENV_VAR] = GUEST_OUT_DIR
    env_words = " ".join(shlex.quote(f"{key}={value}") for key, value in sorted(job_env.items()))
    quoted_cwd = shlex.quote(cwd)
    return (
        "cut -d' ' -f1 /proc/uptime > /run/vmjob/uptime\n"
        f"mkdir -p {GUEST_OUT_DIR}\n"
        f"cd {quoted_cwd} || {{ echo 'vmcan: cannot cd to '{quoted_cwd}; exit 125; }}\n"
        f"exec env -i {env_words} {shlex.join(argv)}\n"
    )


def _qemu_argv(qemu: str, kernel: Path, initramfs: Path, job_dir: Path, settings: VmSettings) -> list[str]:
    return [
        qemu,
        "-nodefaults",  # no VGA, NIC, floppy, CD: less to emulate and probe
        "-no-reboot",  # the guest ends the VM with `reboot -f` (and on panic)
        "-display", "none",
        "-accel", "tcg",
        "-cpu", "max",  # numpy 2.x needs SSE4.2/POPCNT, which qemu64 lacks
        "-m", str(settings.memory_mib),
        "-smp", str(settings.cpu_count),
        "-kernel", str(kernel),
        "-initrd", str(initramfs),
        # panic=-1: a panic reboots at once, which -no-reboot turns into exit.
        "-append", "console=ttyS0 quiet panic=-1",
        "-serial", f"file:{job_dir / 'console.log'}",
        "-virtfs", "local,path=/,mount_tag=hostroot,security_model=none,readonly=on,multidevs=remap",
        "-virtfs", f"local,path={job_dir},mount_tag=vmjob,security_model=none",
    ]


def _read(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except FileNotFoundError:
        return ""


def _tail(text: str) -> str:
    return text[-_CONSOLE_TAIL_CHARS:]


def _boot_failure(console: str, qemu_stderr: str, what: str) -> VmBootError:
    if _INIT_FAILED_MARKER in console:
        reason = console.split(_INIT_FAILED_MARKER, 1)[1].splitlines()[0].strip()
        what = f"guest /init failed: {reason}"
    elif _PANIC_MARKER in console:
        what = "guest kernel panic"
    return VmBootError(
        f"{what}\n--- qemu stderr ---\n{_tail(qemu_stderr)}\n--- guest console (tail) ---\n{_tail(console)}"
    )


def run_in_can_vm(
    argv: list[str],
    *,
    cwd: str | os.PathLike[str],
    timeout_s: float = 240.0,
    env: dict[str, str] | None = None,
    settings: VmSettings = VmSettings(),
) -> VmResult:
    """Boot the VM, run argv in cwd with vcan0 up, and return its status and output.

    cwd and every path in argv are host paths: the guest sees the host root
    at the same place. env replaces the job's whole environment; by default
    it is default_guest_env(). IN_VM_ENV_VAR=1 is always added.

    Raises VmSetupError, VmBootError or VmJobTimeoutError when the job could
    not run to completion; a job that runs and fails is a VmResult with a
    non-zero returncode.
    """
    kernel, initramfs, qemu = check_vm_available(settings)
    guest_cwd = Path(cwd).resolve()
    if not guest_cwd.is_dir():
        # The guest sees the host's tree, so this would fail there too, after a boot.
        raise NotADirectoryError(f"cwd {guest_cwd} is not a directory on the host")
    job_env = default_guest_env() if env is None else dict(env)
    job_dir = Path(tempfile.mkdtemp(prefix="vmcan-"))
    try:
        (job_dir / "job.sh").write_text(_job_script(list(argv), os.fspath(guest_cwd), job_env))
        console_path = job_dir / "console.log"
        stderr_path = job_dir / "qemu-stderr.log"
        started = time.monotonic()
        with open(stderr_path, "wb") as qemu_stderr:
            process = subprocess.Popen(
                _qemu_argv(qemu, kernel, initramfs, job_dir, settings),
                stdin=subprocess.DEVNULL,
                stdout=qemu_stderr,
                stderr=qemu_stderr,
            )
        try:
            boot_s = _wait_for_ready(process, console_path, stderr_path, started, settings.boot_timeout_s)
            _wait_for_exit(process, job_dir, started, timeout_s)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
        total_s = time.monotonic() - started
        console = _read(console_path)
        rc_text = _read(job_dir / "rc").strip()
        if not rc_text:
            raise _boot_failure(
                console, _read(stderr_path), "guest stopped without reporting the job's exit status"
            )
        uptime_text = _read(job_dir / "uptime").strip()
        return VmResult(
            returncode=int(rc_text),
            output=_read(job_dir / "output"),
            console=console,
            boot_s=boot_s,
            total_s=total_s,
            guest_uptime_at_job_start_s=float(uptime_text) if uptime_text else None,
            out_files=_collect_out_files(job_dir / "out"),
        )
    finally:
        shutil.rmtree(job_dir, ignore_errors=True)


def _collect_out_files(out_dir: Path) -> dict[str, bytes]:
    if not out_dir.is_dir():
        return {}
    return {path.name: path.read_bytes() for path in sorted(out_dir.iterdir()) if path.is_file()}


def _wait_for_ready(
    process: subprocess.Popen[bytes],
    console_path: Path,
    stderr_path: Path,
    started: float,
    boot_timeout_s: float,
) -> float:
    """Poll the console until /init says it is about to run the job."""
    while True:
        console = _read(console_path)
        if _READY_MARKER in console:
            return time.monotonic() - started
        if process.poll() is not None:
            # Read again: the marker may have landed between the two checks.
            console = _read(console_path)
            if _READY_MARKER in console:
                return time.monotonic() - started
            what = f"qemu exited with status {process.returncode} before the guest was ready"
            raise _boot_failure(console, _read(stderr_path), what)
        if time.monotonic() - started > boot_timeout_s:
            what = f"guest not ready after {boot_timeout_s:.0f} s (boot timeout)"
            raise _boot_failure(console, _read(stderr_path), what)
        time.sleep(_POLL_INTERVAL_S)


def _wait_for_exit(process: subprocess.Popen[bytes], job_dir: Path, started: float, timeout_s: float) -> None:
    remaining_s = timeout_s - (time.monotonic() - started)
    try:
        process.wait(timeout=max(remaining_s, 0.0))
    except subprocess.TimeoutExpired:
        raise VmJobTimeoutError(
            f"job did not finish within {timeout_s:.0f} s (VM killed)\n"
            f"--- job output so far (tail) ---\n{_tail(_read(job_dir / 'output'))}"
        ) from None
