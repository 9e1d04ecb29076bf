"""Imports point one way: gateway → gateway.core, gateway → drivers; never back.

The numerical core imports numpy/scipy/filterpy/numba and the standard library's
non-I/O parts only, and never opens a file; drivers never import the gateway.
"""
import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CORE_ALLOWED_THIRD_PARTY = {"numpy", "scipy", "filterpy", "numba"}
CORE_FORBIDDEN_STDLIB = {"asyncio", "socket", "select", "selectors", "subprocess", "threading", "tty",
                         "termios", "io", "pathlib", "shutil", "tempfile", "signal", "logging", "csv", "json"}


def imports_of(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.append(node.module)
    return names


def python_files(folder: str) -> list[Path]:
    return sorted((ROOT / folder).rglob("*.py"))


@pytest.mark.parametrize("path", python_files("gateway/core"), ids=lambda p: str(p.relative_to(ROOT)))
def test_core_has_no_io_and_no_outward_imports(path):
    for name in imports_of(path):
        top = name.split(".")[0]
        if name.startswith("gateway."):
            assert name.startswith("gateway.core"), f"{path.name} imports {name}"
        elif top in sys.stdlib_module_names or top == "__future__":
            assert top not in CORE_FORBIDDEN_STDLIB, f"{path.name} imports {name} (I/O belongs outside the core)"
        else:
            assert top in CORE_ALLOWED_THIRD_PARTY, f"{path.name} imports {name}"
    tree = ast.parse(path.read_text(encoding="utf-8"))
    calls = [n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]
    assert "open" not in calls and "print" not in calls, f"{path.name} does I/O"


@pytest.mark.parametrize("path", python_files("drivers"), ids=lambda p: str(p.relative_to(ROOT)))
def test_drivers_never_import_the_gateway(path):
    for name in imports_of(path):
        assert name.split(".")[0] != "gateway", f"{path.name} imports {name}"


@pytest.mark.parametrize("path", python_files("gateway/daemon"), ids=lambda p: str(p.relative_to(ROOT)))
def test_the_daemon_needs_nothing_of_the_offline_side(path):
    for name in imports_of(path):
        assert not name.startswith("gateway.offline") and not name.startswith("gateway.commands"), \
            f"{path.name} imports {name}"


@pytest.mark.parametrize("path", python_files("gateway/offline"), ids=lambda p: str(p.relative_to(ROOT)))
def test_the_offline_side_needs_nothing_of_the_daemon(path):
    for name in imports_of(path):
        assert not name.startswith("gateway.daemon") and not name.startswith("gateway.commands"), \
            f"{path.name} imports {name}"


@pytest.mark.parametrize("path", python_files("gateway") + python_files("drivers"),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_the_shipped_code_needs_no_tests_benchmarks_or_test_helpers(path):
    """gateway/ and drivers/ are what the wheel carries; tests/, testing/ and benchmarks/ are not in it."""
    for name in imports_of(path):
        assert name.split(".")[0] not in {"tests", "testing", "benchmarks"}, f"{path.name} imports {name}"


@pytest.mark.parametrize("path", python_files("tests") + python_files("testing"),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_tests_and_their_helpers_never_import_a_benchmark(path):
    """Benchmarks measure; what tests and benchmarks share lives in testing/."""
    for name in imports_of(path):
        assert name.split(".")[0] != "benchmarks", f"{path.name} imports {name}"
