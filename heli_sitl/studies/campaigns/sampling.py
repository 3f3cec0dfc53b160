"""The sample table of a campaign: one row of values per flight, from the spec's seed.

``random``, ``lhs`` and ``sobol`` draw points in the unit cube (numpy's PCG64, and
scipy.stats.qmc's LatinHypercube and scrambled Sobol', seeded) and map each coordinate
through its distribution's inverse CDF, so a point's marginals are the declared ones;
``choice`` takes ``floor(u k)``. ``grid`` is the Cartesian product of the levels (the
first key varies slowest). ``saltelli`` is SALib's Saltelli/Sobol' design for ``samples``
base points, ``samples (2 d + 2)`` flights, drawn on the unit cube and mapped the same way.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy import stats
from scipy.stats import qmc

from heli_common.state import FloatArray
from heli_sitl.studies.campaigns.spec import CampaignSpec, Vary


def _ppf(v: Vary, u: FloatArray) -> FloatArray:
    if v.dist == "uniform":
        return v.low + (v.high - v.low) * u
    if v.dist == "normal":
        return np.asarray(stats.norm.ppf(u, loc=v.mean, scale=v.sd))
    if v.dist == "truncnormal":
        a, b = (v.low - v.mean) / v.sd, (v.high - v.mean) / v.sd
        return np.asarray(stats.truncnorm.ppf(u, a, b, loc=v.mean, scale=v.sd))
    levels = np.asarray(v.levels(), dtype=float)  # choice
    picked: FloatArray = levels[np.minimum((u * levels.size).astype(int), levels.size - 1)]
    return picked


def unit_points(spec: CampaignSpec) -> FloatArray:
    """The sampler's points in the open unit cube, one row per flight."""
    d = len(spec.vary)
    n = spec.samples
    if spec.sampler == "random":
        pts: FloatArray = np.random.default_rng(spec.seed).random((n, d))
        return pts
    if spec.sampler == "lhs":
        return np.asarray(qmc.LatinHypercube(d=d, seed=spec.seed).random(n))
    if spec.sampler == "sobol":
        # n need not be a power of two (scipy warns that balance is lost: we accept it)
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            return np.asarray(qmc.Sobol(d=d, scramble=True, seed=spec.seed).random(n))
    if spec.sampler == "saltelli":
        from SALib.sample import sobol as salib_sobol

        problem = saltelli_problem(spec)
        raw = salib_sobol.sample(problem, n, calc_second_order=False, seed=spec.seed)
        design = np.asarray(raw, dtype=float)
        # strictly inside the cube: a normal's ppf is infinite at 0 and 1
        inside: FloatArray = np.clip(design, 1e-12, 1.0 - 1e-12)
        return inside
    raise ValueError(f"not a unit-cube sampler: {spec.sampler}")


def saltelli_problem(spec: CampaignSpec) -> dict[str, object]:
    """SALib's problem on the unit cube (the values are mapped afterwards)."""
    return {"num_vars": len(spec.vary), "names": list(spec.keys), "bounds": [[0.0, 1.0]] * len(spec.vary)}


def sample_table(spec: CampaignSpec) -> FloatArray:
    """(flights, varied settings): the value of each setting for each flight."""
    if spec.sampler == "grid":
        return np.array(list(itertools.product(*(v.levels() for v in spec.vary))), dtype=float)
    u = unit_points(spec)
    return np.column_stack([_ppf(v, u[:, j]) for j, v in enumerate(spec.vary)])


def flight_count(spec: CampaignSpec) -> int:
    if spec.sampler == "grid":
        return math.prod(len(v.levels()) for v in spec.vary)
    if spec.sampler == "saltelli":
        return spec.samples * (len(spec.vary) + 2)
    return spec.samples
