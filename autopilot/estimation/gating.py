"""An innovation gate's bookkeeping, shared by the per-axis filters and the navigation filter.

A measurement whose NIS is inside the gate is accepted; a run of rejections longer than the
filter's limit means the filter, not the sensor, is wrong, and the caller resets to the
measurement (the recovery docs/estimator.md describes); otherwise it is rejected. The
counters live in the caller's flat state at offsets it passes.
"""

from __future__ import annotations

from scipy.special import gammaincinv

from heli_common.jit import njit
from heli_common.state import FloatArray


def chi2_quantile(probability: float, dof: int) -> float:
    """The gate on a normalised innovation squared: the chi-square quantile, 2 P^-1(dof/2, p).

    scipy.stats.chi2.ppf computes exactly this (the same bits); scipy.stats itself costs an
    autopilot process 0.6 s to import, scipy.special a fraction of it."""
    return float(2.0 * gammaincinv(0.5 * dof, probability))


# measurement flags in a filter's delayed-fusion record
M_NONE, M_PENDING, M_ACCEPTED, M_RESET = 0.0, 1.0, 2.0, 3.0


@njit
def gate_outcome(
    st: FloatArray, nis: float, gate: float, max_consec: float, i_ok: int, i_consec: int, i_reset: int,
    i_reject: int,
) -> float:  # fmt: skip
    """M_ACCEPTED, M_RESET or M_NONE (rejected) for ``nis`` against ``gate``, counting it in
    ``st[i_ok]``, ``st[i_reset]`` or ``st[i_reject]``; ``st[i_consec]`` counts the rejections
    in a row (a reset after ``max_consec`` of them)."""
    if nis <= gate:
        st[i_ok] += 1.0
        st[i_consec] = 0.0
        return M_ACCEPTED
    if st[i_consec] >= max_consec:
        st[i_reset] += 1.0
        st[i_consec] = 0.0
        return M_RESET
    st[i_reject] += 1.0
    st[i_consec] += 1.0
    return M_NONE
