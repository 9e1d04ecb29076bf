"""The hostile files of issue 16, built in one place for the tests
(tests/offline/test_recording_hostile.py) and the robustness benchmark
(benchmarks/daemon/robustness_benchmark.py), so both attack the commands with the same bytes.

Each builder writes one file and returns its path; the randomness is seeded. Recordings
are built from a simulated run of the paper's strokes (`simulated_run`), raw form with
its reference, or in the acceleration form where the attack is on the values.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
from gateway.core.simulator import simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.offline.recording import MAX_LINE_BYTES, write_recording

# a field longer than Python's csv module accepts by default (csv.field_size_limit())
LONG_FIELD_CHARS = 140_000


def simulated_run(strokes: int = 3, seed: int = 21) -> tuple[dict[str, str], dict[str, np.ndarray]]:
    """(metadata, columns) of a raw recording: the paper's strokes as the board sends them."""
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=strokes)), seed=seed)
    return {"tick_hz": f"{run.tick_hz:g}", "axis": "x"}, run.recording_columns()


def write_raw(path: Path, sim, **replace) -> Path:
    """The simulated raw recording with some columns replaced."""
    meta, cols = sim
    write_recording(path, meta, {**cols, **replace})
    return path


def seq_counting_down(path: Path, sim) -> Path:
    n = sim[1]["seq"].size
    return write_raw(path, sim, seq=(60000 - np.arange(n)) % 65536)


def seq_repeating(path: Path, sim) -> Path:
    return write_raw(path, sim, seq=np.full(sim[1]["seq"].size, 7))


def truncated(path: Path, sim) -> Path:
    """A logger killed mid-row: the last line cut 9 bytes short of its end."""
    write_raw(path, sim)
    path.write_bytes(path.read_bytes()[:-9])
    return path


def non_utf8_in_the_data(path: Path, sim, from_end: int = 50) -> Path:
    """One byte 0xFF `from_end` bytes before the end (returned: the path; offset = size − from_end)."""
    write_raw(path, sim)
    data = path.read_bytes()
    at = len(data) - from_end
    path.write_bytes(data[:at] + b"\xff" + data[at + 1:])
    return path


def long_field(path: Path, last_line: bool = False) -> Path:
    """An acceleration-form recording whose third line has a field of LONG_FIELD_CHARS
    characters (on the last line, without a newline, if last_line)."""
    assert LONG_FIELD_CHARS > MAX_LINE_BYTES
    field = "9" * LONG_FIELD_CHARS
    path.write_text("t_s,acc_x_mps2\n0,1\n0.1," + field + ("" if last_line else "\n0.2,1\n"))
    return path


def impossible_samples(path: Path, values: dict[int, float] | None = None, n: int = 4000) -> Path:
    """2 mg of seeded noise at 500 samples/s with samples replaced: {index: m/s²}; by
    default one sample of 1e300 (index 2500)."""
    t = np.arange(n) * 0.002
    acc = np.random.default_rng(3).normal(0, 0.02, n)
    for at, value in (values or {2500: 1e300}).items():
        acc[at] = value
    write_recording(path, {"axis": "x"}, {"t_s": t, "acc_x_mps2": acc})
    return path


def quiet_rest(path: Path, step_mg: float | None, strokes: int = 3, seed: int = 21) -> Path:
    """The strokes in the acceleration form with a rest that has no noise: the true
    acceleration alone (step_mg None), or the true one plus 2 mg of seeded noise,
    quantised to step_mg (10 mg: every rest sample the same value)."""
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=strokes)), seed=seed)
    acc = run.ref_acc_mps2.copy()
    if step_mg is not None:
        step = step_mg * 1e-3 * STANDARD_GRAVITY_MPS2
        noise = np.random.default_rng(seed).normal(0, 2e-3 * STANDARD_GRAVITY_MPS2, acc.size)
        acc = np.round((acc + noise) / step) * step
    write_recording(path, {"axis": "x"}, {"t_s": run.t_s - run.t_s[0], "acc_x_mps2": acc,
                                          "ref_pos_m": run.ref_pos_m, "ref_vel_mps": run.ref_vel_mps})
    return path


def nested_toml(path: Path, depth: int = 5000, inline_tables: bool = False) -> Path:
    """A config nested `depth` deep: arrays, or inline tables."""
    if inline_tables:
        path.write_text("a = " + "{b = " * depth + "1" + "}" * depth + "\n")
    else:
        path.write_text("a = " + "[" * depth + "]" * depth + "\n")
    return path


def without_metadata(path: Path, out: Path) -> Path:
    """A recording as another logger would write it: the same CSV without its `# key=value`
    lines (for `adxlgw import`)."""
    with open(path, "rb") as src, open(out, "wb") as dst:
        dst.writelines(line for line in src if not line.startswith(b"#"))
    return out


# Started from this launcher, not from the caller: Linux counts in a child's peak RSS the
# memory of the process it was forked from (the parent's pages it held until exec), so a
# command forked from pytest or the benchmark (~300 MB with numpy and numba) would show at
# least that. The launcher is a bare interpreter (-I -S: a few MB).
_LAUNCHER = """
import resource, subprocess, sys, time
started = time.monotonic()
code = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL).returncode
wall = time.monotonic() - started
print(code, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, wall)
"""


def run_measured(cmd: list, cwd=None, timeout: float = 600) -> tuple[int, str, int, float]:
    """Run cmd in its own process: (exit code, stderr, its peak resident memory in bytes,
    wall time in s). Its stdout is discarded."""
    r = subprocess.run([sys.executable, "-I", "-S", "-c", _LAUNCHER, *map(str, cmd)], cwd=cwd,
                       capture_output=True, text=True, timeout=timeout)
    code, maxrss_kb, wall = r.stdout.split()
    return int(code), r.stderr, int(maxrss_kb) * 1024, float(wall)
