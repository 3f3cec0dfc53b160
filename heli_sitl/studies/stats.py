"""Intervals for what campaigns and comparisons claim: a loss rate, a median, a 95th percentile,
a paired difference. Pure functions over arrays; every random draw from a given seed.

* :func:`loss_rate`: the Clopper-Pearson (exact binomial) interval: 0 lost of 1000 is a rate
  in [0, 0.37 %] at 95 %, not "zero";
* :func:`percentile_ci`: the percentile bootstrap of a percentile (Efron & Tibshirani 1993,
  ch. 13), resampling the flights;
* :func:`paired`: two contenders flown on the same samples: the bootstrap interval of the
  median of the per-sample differences and the Wilcoxon signed-rank test (scipy) of them;
* :func:`holm`: a table's p-values adjusted as one family (Holm 1979), so that a reader may
  hold each against 0.05 however many tests the table makes.

A grid (a campaign's ``sampler = "grid"``) is a map, not a sample: its counts are facts of
the grid, and no interval is drawn over them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import stats as sps

CONFIDENCE = 0.95
N_BOOT = 2000


@dataclass(frozen=True)
class Interval:
    """An estimate and its two-sided interval at ``confidence``."""

    estimate: float
    lo: float
    hi: float
    confidence: float = CONFIDENCE

    @classmethod
    def of_grid(cls, value: float) -> Interval:
        """A figure of a grid (a map, not a sample): the value, no interval."""
        return cls(value, math.nan, math.nan)

    @property
    def bare(self) -> bool:
        """No interval: a grid's figure."""
        return math.isnan(self.lo) and math.isnan(self.hi) and not math.isnan(self.estimate)

    def __str__(self) -> str:
        if self.bare:
            return f"{self.estimate:.4g} (grid)"
        return f"{self.estimate:.4g} [{self.lo:.4g}, {self.hi:.4g}]"

    def pct(self) -> str:
        """As percentages (a rate)."""
        if self.bare:
            return f"{100 * self.estimate:.2f} % (grid)"
        return f"{100 * self.estimate:.2f} % [{100 * self.lo:.2f}, {100 * self.hi:.2f}] %"


def loss_rate(lost: int, flights: int, confidence: float = CONFIDENCE) -> Interval:
    """``lost`` of ``flights`` as a rate with its exact (Clopper-Pearson) interval."""
    if flights <= 0 or not 0 <= lost <= flights:
        raise ValueError(f"need 0 <= lost <= flights and flights > 0, got {lost} of {flights}")
    a = 1.0 - confidence
    lo = 0.0 if lost == 0 else float(sps.beta.ppf(a / 2, lost, flights - lost + 1))
    hi = 1.0 if lost == flights else float(sps.beta.ppf(1 - a / 2, lost + 1, flights - lost))
    return Interval(lost / flights, lo, hi, confidence)


def _finite(values: npt.ArrayLike) -> npt.NDArray[np.float64]:
    v = np.asarray(values, dtype=np.float64)
    out: npt.NDArray[np.float64] = v[np.isfinite(v)]
    return out


def percentile_ci(
    values: npt.ArrayLike, q: float, seed: int = 0, confidence: float = CONFIDENCE, n_boot: int = N_BOOT
) -> Interval:
    """The ``q``-th percentile (0-100) of the finite ``values`` and its bootstrap interval."""
    v = _finite(values)
    if v.size == 0:
        return Interval(math.nan, math.nan, math.nan, confidence)
    rng = np.random.default_rng(seed)
    boots = np.percentile(v[rng.integers(0, v.size, (n_boot, v.size))], q, axis=1)
    a = 100.0 * (1.0 - confidence) / 2
    lo, hi = np.percentile(boots, [a, 100.0 - a])
    return Interval(float(np.percentile(v, q)), float(lo), float(hi), confidence)


@dataclass(frozen=True)
class Paired:
    """Contender A against B on the same samples, lower being better. A non-finite value is a
    lost flight: never a dropped pair. Where one of the pair is lost the other wins it, as
    the largest difference of all (the signed-rank test and ``a_better_fraction`` count it);
    where both are lost it is a tie. The medians are of each side's finite values (their
    losses counted in ``lost_a``, ``lost_b``), the median difference of the pairs both flew."""

    n: int  # every pair
    median_a: Interval
    median_b: Interval
    median_diff: Interval  # of a - b, over the pairs both flew
    wilcoxon_p: float  # two-sided signed-rank test of a - b, losses included; nan when all tie
    a_better_fraction: float  # of all pairs where a < b (a lost pair counts against the loser)
    lost_a: int = 0
    lost_b: int = 0


def paired(a: npt.ArrayLike, b: npt.ArrayLike, seed: int = 0, confidence: float = CONFIDENCE) -> Paired:
    x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if x.shape != y.shape:
        raise ValueError(f"paired samples need the same shape, got {x.shape} and {y.shape}")
    fa, fb = np.isfinite(x), np.isfinite(y)
    both = fa & fb
    d_flown = x[both] - y[both]
    worst = 2.0 * float(np.max(np.abs(d_flown))) + 1.0 if d_flown.size else 1.0
    d = np.zeros(x.shape)  # both lost: a tie
    d[both] = d_flown
    d[~fa & fb] = worst  # a lost, b flew: b wins, by more than any flown difference
    d[fa & ~fb] = -worst
    p = math.nan
    if d.size and np.any(d != 0.0):
        p = float(sps.wilcoxon(d).pvalue)
    return Paired(
        n=int(d.size),
        median_a=percentile_ci(x, 50, seed, confidence),
        median_b=percentile_ci(y, 50, seed, confidence),
        median_diff=percentile_ci(d_flown, 50, seed, confidence),
        wilcoxon_p=p,
        a_better_fraction=float(np.mean(d < 0.0)) if d.size else math.nan,
        lost_a=int(np.count_nonzero(~fa)),
        lost_b=int(np.count_nonzero(~fb)),
    )


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjustment of a family of p-values (S. Holm, "A simple sequentially
    rejective multiple test procedure", Scand. J. Statist. 6, 1979): the i-th smallest of the
    m tests is scaled by m - i + 1, the running maximum taken and capped at 1, so each
    adjusted p is held against the family's level directly. A NaN (no test made) stays NaN
    and is not one of the family."""
    p = np.asarray(p_values, dtype=float)
    out = np.full(p.shape, math.nan)
    tested = np.flatnonzero(np.isfinite(p))
    order = tested[np.argsort(p[tested], kind="stable")]
    m = order.size
    running = 0.0
    for i, k in enumerate(order):
        running = max(running, min(1.0, (m - i) * float(p[k])))
        out[k] = running
    return [float(v) for v in out]
