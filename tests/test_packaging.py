"""What the package declares and carries: ranges for users, exact versions for CI,
test-only libraries in the test extra, the unit, DBC and default config installable
from the package itself."""
import ast
import contextlib
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest
from packaging.requirements import Requirement

from gateway.config import default_config_text

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "gateway.cli"]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
TEST_ONLY = {"pytest", "hypothesis", "filterpy", "cantools", "pyte", "ruff"}


def constraints() -> dict[str, str]:
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, version = line.split("==")
            pins[name.lower().replace("_", "-")] = version
    return pins


def test_dependencies_are_ranges_and_constraints_pin_each_inside_its_range():
    pins = constraints()
    extras = PYPROJECT["project"]["optional-dependencies"]
    runtime = [Requirement(r) for r in PYPROJECT["project"]["dependencies"]]
    offline = [Requirement(r) for r in extras["offline"]]
    # the test extra pulls in the offline one (the tests run the offline tools)
    test = [Requirement(r) for r in extras["test"] if not r.startswith("adxl-gateway[")]
    assert "adxl-gateway[offline]" in extras["test"]
    for req in runtime + offline + test:
        assert not any(spec.operator == "==" for spec in req.specifier), f"{req} is pinned in pyproject"
        assert req.name in pins, f"{req.name} has no exact version in constraints.txt"
        assert req.specifier.contains(pins[req.name]), f"constraints.txt {req.name}=={pins[req.name]} outside {req}"
    assert {r.name for r in test} >= TEST_ONLY
    assert not {r.name for r in runtime + offline} & TEST_ONLY
    # the daemon's install carries none of the offline tools' libraries (tests/core/test_chi2.py:
    # the daemon imports none of them)
    assert not {r.name for r in runtime} & {"scipy", "matplotlib", "pyarrow", "polars", "tqdm", "rich"}


def test_the_installed_code_never_imports_the_test_only_libraries():
    for folder in ("gateway", "drivers"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                         else [node.module] if isinstance(node, ast.ImportFrom) and node.module else [])
                for name in names:
                    assert name.split(".")[0] not in TEST_ONLY, f"{path.relative_to(ROOT)} imports {name}"


def test_version_is_the_package_version():
    r = subprocess.run([*CLI, "--version"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0
    assert r.stdout.strip() == f"adxlgw {PYPROJECT['project']['version']}"


def test_install_files_writes_unit_config_dbc_and_keeps_an_edited_config(tmp_path):
    r = subprocess.run([*CLI, "install-files", "--root", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    unit = (tmp_path / "etc/systemd/system/adxl-gateway.service").read_text()
    shipped = (ROOT / "systemd/adxl-gateway.service").read_text()
    program = Path(sys.executable).parent / "adxlgw"
    assert unit == shipped.replace("/opt/adxl-gateway/venv/bin/adxlgw", str(program))
    assert f"ExecStart={program} run --config /etc/adxl-gateway/gateway.toml" in unit
    config = tmp_path / "etc/adxl-gateway/gateway.toml"
    assert config.read_text() == default_config_text()
    assert (tmp_path / "usr/share/adxl-gateway/adxl-gateway.dbc").read_text() == (
        ROOT / "config/adxl-gateway.dbc").read_text()
    assert (tmp_path / "usr/share/doc/adxl-gateway/daemon.md").read_text() == (ROOT / "docs/daemon.md").read_text()
    config.write_text("# edited\n")
    r = subprocess.run([*CLI, "install-files", "--root", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and f"kept {config} (exists)" in r.stdout
    assert config.read_text() == "# edited\n"


@pytest.mark.parametrize("name, expected", [
    ("dbc", lambda: (ROOT / "config/adxl-gateway.dbc").read_text()),
    ("config", default_config_text),
])
def test_install_files_prints_one(name, expected):
    r = subprocess.run([*CLI, "install-files", "--print", name], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout == expected()


def test_install_files_into_a_place_it_cannot_write_is_one_line(tmp_path):
    blocker = tmp_path / "etc"
    blocker.write_text("a file where a directory should be")
    r = subprocess.run([*CLI, "install-files", "--root", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.startswith(f"adxlgw install-files: error: cannot write {tmp_path}/etc/systemd/system/")


@pytest.mark.slow
def test_the_wheel_carries_the_files_not_links(tmp_path):
    # built from a copy: setuptools writes build/ into the tree it builds
    source = tmp_path / "src"
    shutil.copytree(ROOT, source, symlinks=True,
                    ignore=shutil.ignore_patterns(".git", ".venv", "datasets", "build", "__pycache__", "*.egg-info"))
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", str(source), "-w", str(tmp_path)],
                       capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    (wheel,) = tmp_path.glob("adxl_gateway-*.whl")
    with zipfile.ZipFile(wheel) as zf:
        for inside, source in [("gateway/data/adxl-gateway.service", "systemd/adxl-gateway.service"),
                               ("gateway/data/adxl-gateway.dbc", "config/adxl-gateway.dbc"),
                               ("gateway/data/daemon.md", "docs/daemon.md")]:
            assert zf.read(inside) == (ROOT / source).read_bytes()
        metadata = zf.read(next(n for n in zf.namelist() if n.endswith("/METADATA"))).decode()
    assert "Requires-Dist: numba<1,>=0.60" in metadata
    assert 'Requires-Dist: filterpy<2.1,>=1.4.5; extra == "test"' in metadata


def _runtime_closure() -> set[str]:
    """The distributions a slim install brings: the runtime dependencies and, as
    installed here, what they require in turn (extras' requirements left out)."""
    from importlib.metadata import PackageNotFoundError, requires

    from packaging.utils import canonicalize_name

    todo = [Requirement(r) for r in PYPROJECT["project"]["dependencies"]]
    seen: set[str] = set()
    while todo:
        req = todo.pop()
        name = canonicalize_name(req.name)
        if name in seen or (req.marker is not None and not req.marker.evaluate({"extra": ""})):
            continue
        seen.add(name)
        with contextlib.suppress(PackageNotFoundError):  # an optional one not installed here
            todo.extend(Requirement(r) for r in requires(name) or [])
    return seen


def test_the_daemon_imports_only_what_the_slim_install_brings():
    """Every module `adxlgw run` imports is the standard library's, the project's own or
    a runtime dependency's (pyproject's [project] dependencies and what they require):
    a library kept in an extra but imported by the daemon breaks the slim install."""
    from importlib.metadata import packages_distributions

    from packaging.utils import canonicalize_name

    code = ("import sys, gateway.daemon.supervisor, gateway.daemon.settings, gateway.commands.run; "
            "print('\\n'.join(sorted({m.split('.')[0] for m in sys.modules})))")
    top_level = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                               check=True, cwd=ROOT).stdout.split()
    owners = packages_distributions()
    allowed = _runtime_closure()
    outside = []
    for module in top_level:
        if module in sys.stdlib_module_names or module in ("gateway", "drivers") or module.startswith("_"):
            continue
        if module == "scipy":  # numba imports the bare package where it is installed, to read its
            continue  # version; none of its parts (tests/core/test_chi2.py checks that)
        dists = {canonicalize_name(d) for d in owners.get(module, [])}
        if dists and not dists & allowed:
            outside.append(f"{module} (from {', '.join(sorted(dists))})")
    assert not outside, f"the daemon imports libraries a slim install lacks: {outside}"
