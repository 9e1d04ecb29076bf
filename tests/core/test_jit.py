"""numba refused at start (systemd's MemoryDenyWriteExecute=yes): plain Python, one
warning, the same numbers, never a traceback (gateway/core/jit.py)."""
import ctypes
import os
import subprocess
import sys
from pathlib import Path

CLI = [sys.executable, "-m", "gateway.cli"]
PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN = 65, 1  # linux/prctl.h, Linux ≥ 6.3


def deny_write_execute() -> None:
    """In the child before exec: what MemoryDenyWriteExecute=yes does, from the kernel
    itself (newer systemd sets exactly this prctl; older ones a seccomp filter with the
    same effect on mmap/mprotect). Inherited across execve."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_MDWE) refused: this kernel cannot deny W+X memory")


def numba_off_env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "ADXLGW_NO_JIT"}
    return {**env, **extra}


def simulated(tmp_path: Path) -> Path:
    path = tmp_path / "sim.csv"
    subprocess.run([*CLI, "simulate", "--strokes", "2", "--seed", "1", "--out", str(path)], check=True,
                   capture_output=True, timeout=120)
    return path


def estimate(recording: Path, out: Path, **popen) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, "estimate", str(recording), "--method", "realtime", "--out", str(out)],
                          capture_output=True, text=True, timeout=300, **popen)


def assert_one_warning_no_traceback(stderr: str, cause: str) -> None:
    warnings = [line for line in stderr.splitlines() if line.startswith("WARNING")]
    assert len(warnings) == 1, stderr
    assert cause in warnings[0] and "run as plain Python" in warnings[0]
    assert "Traceback" not in stderr


def test_under_denied_write_execute_memory_the_estimate_runs_as_plain_python(tmp_path):
    recording = simulated(tmp_path)
    refused = estimate(recording, tmp_path / "refused.csv", env=numba_off_env(), preexec_fn=deny_write_execute)
    assert refused.returncode == 0, refused.stderr
    assert_one_warning_no_traceback(refused.stderr, "numba cannot start: PermissionError")
    # the oracle: the same functions switched to plain Python on purpose, which says nothing
    chosen = estimate(recording, tmp_path / "chosen.csv", env=numba_off_env(ADXLGW_NO_JIT="1"))
    assert chosen.returncode == 0 and "WARNING" not in chosen.stderr
    assert (tmp_path / "refused.csv").read_bytes() == (tmp_path / "chosen.csv").read_bytes()


def test_help_under_denied_write_execute_memory(tmp_path):
    r = subprocess.run([*CLI, "--help"], capture_output=True, text=True, timeout=120, env=numba_off_env(),
                       preexec_fn=deny_write_execute)
    assert r.returncode == 0 and "usage: adxlgw" in r.stdout
    assert_one_warning_no_traceback(r.stderr, "cannot allocate executable memory")


def test_any_exception_from_numba_import_falls_back(tmp_path):
    """Not only PermissionError: whatever a broken numba raises at import (here a
    stand-in package first on the path)."""
    fake = tmp_path / "site" / "numba"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text('raise RuntimeError("llvmlite: no usable LLVM")\n')
    env = numba_off_env(PYTHONPATH=os.pathsep.join([str(fake.parent), str(Path(__file__).resolve().parents[2])]))
    probe = "import gateway.core.jit as j; print(j.JIT_ENABLED, j.JIT_UNAVAILABLE_REASON)"
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False numba cannot start: RuntimeError: llvmlite: no usable LLVM"
    r = subprocess.run([*CLI, "config", "--default"], capture_output=True, text=True, timeout=60, env=env)
    assert r.returncode == 0 and "[serial]" in r.stdout
    assert_one_warning_no_traceback(r.stderr, "RuntimeError: llvmlite: no usable LLVM")


def test_no_jit_by_choice_says_nothing():
    probe = "import gateway.core.jit as j; print(j.JIT_ENABLED, j.JIT_UNAVAILABLE_REASON)"
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60,
                       env=numba_off_env(ADXLGW_NO_JIT="1"))
    assert r.stdout.strip() == "False None"


def test_the_compiled_cache_is_keyed_by_every_source_of_the_project(tmp_path):
    """numba invalidates a cached function only when its own file changes; ours inline code
    of other files (the kernel, standstill.py's tests; the daemon's pipeline, the kernel):
    any change to any source must lead to another cache directory."""
    from gateway import compiled_cache
    from gateway.core import jit

    (tmp_path / "gateway/core").mkdir(parents=True)
    (tmp_path / "drivers").mkdir()
    (tmp_path / "gateway/core/standstill.py").write_text("LIMIT = 4\n")
    (tmp_path / "drivers/board_protocol.py").write_text("SYNC = 0xA5\n")
    before = compiled_cache.sources_digest(str(tmp_path))
    assert compiled_cache.sources_digest(str(tmp_path)) == before
    (tmp_path / "gateway/core/standstill.py").write_text("LIMIT = 5\n")
    after_core = compiled_cache.sources_digest(str(tmp_path))
    (tmp_path / "drivers/board_protocol.py").write_text("SYNC = 0xA6\n")
    assert len({before, after_core, compiled_cache.sources_digest(str(tmp_path))}) == 3
    # under a base of its own (the service's), kept when a child process inherits it
    keyed = compiled_cache.keyed_cache_dir("/var/cache/adxl-gateway", before)
    assert keyed == f"/var/cache/adxl-gateway/numba-{before}"
    assert compiled_cache.keyed_cache_dir(keyed, before) == keyed
    # this process: keyed by this checkout's sources, and numba uses it
    repo = Path(__file__).resolve().parents[2]
    assert Path(os.environ["NUMBA_CACHE_DIR"]).name == f"numba-{compiled_cache.sources_digest(str(repo))}"
    if jit.JIT_ENABLED:
        import numba

        assert os.environ["NUMBA_CACHE_DIR"] == numba.config.CACHE_DIR
