"""Intervals (heli_sitl.studies.stats) against their known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from heli_sitl.studies.stats import loss_rate, paired, percentile_ci


def test_zero_lost_of_1000_is_not_zero() -> None:
    """The exact interval of 0/1000 is [0, 0.368 %] (the "rule of three" says about 0.3 %)."""
    r = loss_rate(0, 1000)
    assert r.estimate == 0.0 and r.lo == 0.0
    assert r.hi == pytest.approx(1 - 0.025 ** (1 / 1000), rel=1e-9)  # closed form for k = 0
    assert 0.00366 < r.hi < 0.00370
    # 3 of 1000 against 0 of 1000: the intervals overlap, so that difference alone is not significant
    assert loss_rate(3, 1000).lo < r.hi


def test_loss_rate_refuses_impossible_counts() -> None:
    with pytest.raises(ValueError, match="lost <= flights"):
        loss_rate(5, 3)


def test_bootstrap_interval_of_a_median_covers_and_shrinks() -> None:
    rng = np.random.default_rng(0)
    small = percentile_ci(rng.normal(1.0, 1.0, 100), 50, seed=1)
    large = percentile_ci(rng.normal(1.0, 1.0, 2000), 50, seed=1)
    assert small.lo < 1.0 < small.hi and large.lo < 1.0 < large.hi
    # the width goes as 1/sqrt(n): 2*1.96*1.2533/sqrt(n) for a normal median, 0.49 at 100, 0.11 at 2000
    assert 0.3 < small.hi - small.lo < 0.65
    assert 0.07 < large.hi - large.lo < 0.15
    assert percentile_ci([1.0, np.nan, 2.0, 3.0], 50).estimate == 2.0  # NaN (a lost flight) left out


def test_paired_test_finds_a_small_consistent_difference() -> None:
    rng = np.random.default_rng(3)
    base = rng.lognormal(0.0, 1.0, 300)
    p = paired(base * 0.95, base)  # 5 % better on every sample: hidden in the spread, not in the pairs
    assert p.n == 300 and p.a_better_fraction == 1.0
    assert p.wilcoxon_p < 1e-10
    assert p.median_diff.hi < 0.0
    assert p.median_a.lo < p.median_b.estimate < p.median_a.hi  # the unpaired intervals overlap
    same = paired(base, base + rng.normal(0.0, 0.01, 300))
    assert same.wilcoxon_p > 0.01


def test_paired_counts_a_lost_flight_against_the_loser_never_drops_the_pair() -> None:
    """A contender 1 % better where both fly but lost on 20 of 100 samples (NaN, inf): before,
    its 20 losses were dropped and it won every pair (Wilcoxon p 7.8e-15 over the 80)."""
    rng = np.random.default_rng(4)
    base = rng.lognormal(0.0, 0.5, 100)
    a = base * 0.99
    a[:10], a[10:20] = np.nan, np.inf
    p = paired(a, base)
    assert p.n == 100 and (p.lost_a, p.lost_b) == (20, 0)
    assert p.a_better_fraction == 0.8  # the 80 it flew, each 1 % better
    assert p.median_diff.hi < 0.0  # where both flew, a is better
    # the signed-rank test with the 20 losses ranked above every flown difference: the 80
    # small wins still lean its way, far less surely (deterministic: pinned)
    assert p.wilcoxon_p == pytest.approx(0.013861922552593253, rel=1e-9)
    assert paired(base, a).a_better_fraction == 0.2  # the same pairs seen from b: its 20 wins
    tie = paired(np.full(5, np.nan), np.full(5, np.inf))
    assert tie.n == 5 and math.isnan(tie.wilcoxon_p) and tie.a_better_fraction == 0.0


def test_holm_adjusts_a_family_as_holm_1979() -> None:
    """p = (0.01, 0.04, 0.03, 0.005): sorted 0.005, 0.01, 0.03, 0.04 scaled by 4, 3, 2, 1 to
    0.02, 0.03, 0.06, 0.04, the running maximum 0.02, 0.03, 0.06, 0.06; a NaN (no test) is
    no member of the family."""
    from heli_sitl.studies.stats import holm

    assert holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02], rel=1e-12)
    adj = holm([0.01, math.nan, 0.04])
    assert adj[0] == pytest.approx(0.02) and math.isnan(adj[1]) and adj[2] == pytest.approx(0.04)
    assert holm([0.6, 0.7]) == [1.0, 1.0]  # capped at 1
    assert holm([]) == []


def test_a_grid_is_a_map_with_no_interval() -> None:
    """A grid's loss share is a fact of its points: counted, never given a binomial interval."""
    import pyarrow as pa

    from heli_sitl.studies.campaigns.counts import CampaignCounts
    from heli_sitl.studies.stats import Interval

    rows = pa.table({"failed": [False] * 10, "diverged": [True] * 4 + [False] * 6,
                     "converged": [False] * 4 + [True] * 6})  # fmt: skip
    sampled, grid = CampaignCounts.of(rows), CampaignCounts.of(rows, sampled=False)
    assert sampled.loss_rate is not None and sampled.loss_rate.lo < 0.4 < sampled.loss_rate.hi
    assert grid.loss_rate is None and grid.diverged == 4
    assert "40.00 % of the grid's points (a map: no interval)" in grid.line()
    assert "loss_rate" not in grid.as_dict() and "loss_rate" in sampled.as_dict()
    assert Interval.of_grid(0.4).pct() == "40.00 % (grid)" and str(Interval.of_grid(0.25)) == "0.25 (grid)"


def test_the_comparisons_tables_give_holm_adjusted_p_values() -> None:
    """Two contenders against one reference on 40 seeds: each table's p-values are one
    family, adjusted together (the raw Wilcoxon p of each pair, scaled by Holm's rule)."""
    from heli_sitl.studies.comparison import MonteCarloSet, _p, monte_carlo_table
    from heli_sitl.studies.scorecard import FlightScore
    from heli_sitl.studies.stats import holm

    rng = np.random.default_rng(7)
    names = FlightScore.names()

    def score(shift: float) -> FlightScore:
        noisy = {"steady_rms_m": 1.0 + shift + rng.normal(0, 0.1),
                 "transient_peak_m": 2.0 + rng.normal(0, 0.1)}
        return FlightScore(**{n: 0.0 for n in names} | noisy)

    def scores(shift: float) -> tuple[FlightScore, ...]:
        return tuple(score(shift) for _ in range(40))

    ms = MonteCarloSet("gusty", 40, {"ref": scores(0.0), "a": scores(0.03), "b": scores(0.08)}, "ref")
    raw = [ms.against_reference(lab, m).wilcoxon_p for lab in ("a", "b")
           for m in ("steady_rms_m", "transient_peak_m")]  # fmt: skip
    table = monte_carlo_table([ms])
    cells = [line.split(" | ")[-2:] for line in table.splitlines()[3:]]  # a's and b's rows
    shown = [c.rsplit("(", 1)[1].rstrip(") |") for row in cells for c in row]
    assert shown == [_p(p) for p in holm(raw)]
    assert "Holm" in table.splitlines()[0]
