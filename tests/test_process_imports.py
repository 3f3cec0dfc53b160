"""What a process loads to start: the heavy libraries only where they are used, and the
estimators' chi-square gates from scipy.special bit for bit as scipy.stats computes them."""

from __future__ import annotations

import subprocess
import sys

import pytest
from scipy.stats import chi2

from autopilot.estimation.gating import chi2_quantile

HEAVY = ("scipy.stats", "scipy.interpolate", "dronecan", "can", "matplotlib", "pandas")


@pytest.mark.parametrize("module", ["autopilot.cli", "heli_plant.server", "ground.cli"])
def test_a_process_on_mavlink_starts_without_the_heavy_libraries(module: str) -> None:
    code = f"import sys, {module}; print(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         check=True)  # fmt: skip
    assert out.stdout.strip() == "", f"{module} loads {out.stdout.strip()}"


@pytest.mark.parametrize("probability", [0.9, 0.99, 0.999, 0.9999])
@pytest.mark.parametrize("dof", [1, 2, 3, 6])
def test_the_chi_square_gate_is_scipy_stats_own_quantile(probability: float, dof: int) -> None:
    assert chi2_quantile(probability, dof) == float(chi2.ppf(probability, dof))


LOADED_KERNELS = (
    "import sys, numba, {module}\n"
    "print(','.join(sorted({{f'{{n}}.{{k}}' for n, mod in list(sys.modules.items())\n"
    "    if n.split('.')[0] in ('heli_common', 'heli_plant', 'autopilot', 'ground', 'heli_sitl')\n"
    "    for k, v in vars(mod).items()\n"
    "    if isinstance(v, numba.core.registry.CPUDispatcher) and v.signatures}})))"
)


@pytest.mark.parametrize("module", ["autopilot.cli", "heli_plant.server", "ground.cli"])
def test_a_process_runs_no_compiled_code_while_it_imports(module: str) -> None:
    """Loading a kernel costs 0.1-0.5 s of CPU: done at import, every process pays it, most for
    nothing (the plant built its no-world arrays at import: 0.6 s of every plant's start)."""
    out = subprocess.run([sys.executable, "-c", LOADED_KERNELS.format(module=module)], capture_output=True,
                         text=True, timeout=120, check=True)  # fmt: skip
    assert out.stdout.strip() == "", f"{module} loads kernels at import: {out.stdout.strip()}"
