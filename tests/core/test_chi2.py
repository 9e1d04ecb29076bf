"""The daemon's own χ² quantile and tail (gateway/core/chi2.py) against scipy.stats.chi2."""
from __future__ import annotations

import pytest
from scipy.stats import chi2

from gateway.core.chi2 import chi2_isf, chi2_sf


@pytest.mark.parametrize("dof", [0.7, 1.0, 2.0, 5.5, 12.3, 49.0, 50.0, 200.0, 1000.0])
@pytest.mark.parametrize("tail", [0.5, 0.05, 1e-4, 1e-9])
def test_the_quantile_agrees_with_scipy(dof, tail):
    assert chi2_isf(tail, dof) == pytest.approx(chi2.isf(tail, dof), rel=1e-12)


@pytest.mark.parametrize("dof", [1.0, 3.0, 20.0, 400.0])
@pytest.mark.parametrize("x", [0.01, 0.9, 5.0, 30.0, 500.0])
def test_the_tail_agrees_with_scipy(dof, x):
    assert chi2_sf(x, dof) == pytest.approx(chi2.sf(x, dof), rel=1e-11, abs=1e-300)


def test_the_daemon_imports_none_of_the_offline_libraries():
    """What the slim install leaves out (pyproject's [offline] extra). numba imports the
    scipy package itself where it is installed, to check its version: nothing of it more."""
    import subprocess
    import sys

    offline = ("scipy.special", "scipy.stats", "scipy.signal", "scipy.optimize", "scipy.ndimage",
               "scipy.interpolate", "pyarrow", "polars", "matplotlib", "tqdm", "PIL", "fontTools", "rich")
    code = ("import sys, gateway.daemon.supervisor, gateway.daemon.settings, gateway.commands.run; "
            f"print(sorted(m for m in sys.modules if m.startswith({offline!r})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
