"""The estimator kernel's shape (docs/estimation.md, "The kernel's phases"; decision 0125): its
phase modules stay small, and `estimator_kernel` is the one entry every caller imports."""
import ast
from pathlib import Path

import pytest

from gateway.core import estimator_kernel as K

ROOT = Path(__file__).resolve().parents[2]
CORE = ROOT / "gateway" / "core"
KERNEL_MODULES = sorted(CORE.glob("kernel_*.py")) + [CORE / "estimator_kernel.py"]
MAX_MODULE_LINES = 500  # issue 34's bound for a module
MAX_FUNCTION_LINES = 120  # and for a function (a phase)


def test_the_phase_modules_are_there():
    assert {p.stem for p in KERNEL_MODULES} >= {"kernel_layout", "kernel_propagate", "kernel_standstill_judge",
                                                 "kernel_update", "kernel_output", "estimator_kernel"}


@pytest.mark.parametrize("path", KERNEL_MODULES, ids=lambda p: p.name)
def test_a_kernel_module_and_its_functions_stay_small(path):
    source = path.read_text(encoding="utf-8")
    assert source.count("\n") <= MAX_MODULE_LINES, f"{path.name}: {source.count(chr(10))} lines"
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.FunctionDef):
            length = node.end_lineno - node.lineno + 1
            assert length <= MAX_FUNCTION_LINES, f"{path.name}: {node.name} has {length} lines"


def test_the_kernel_has_one_entry():
    """Nothing outside the kernel imports a phase module; estimator_kernel offers all of them."""
    outside = [p for p in (ROOT / "gateway").rglob("*.py") if p not in KERNEL_MODULES]
    outside += [p for folder in ("drivers", "tests", "testing", "benchmarks") for p in (ROOT / folder).rglob("*.py")]
    for path in outside:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            assert not any(n.startswith("gateway.core.kernel_") for n in names), f"{path} imports {names}"
    for path in KERNEL_MODULES[:-1]:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        public = [n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))
                  and not n.name.startswith("_")]
        missing = [name for name in public if not hasattr(K, name)]
        assert not missing, f"estimator_kernel does not offer {path.stem}'s {missing}"
