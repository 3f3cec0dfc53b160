"""Is the navigation filter consistent? NEES over seeded flights, against chi-square.

A filter is consistent when its errors are as large as its covariance says: the
normalised estimation error squared of its 15 navigation states, averaged over N
independent flights, is chi-square with 15 N degrees of freedom divided by N (Bar-Shalom,
Li and Kirubarajan, "Estimation with Applications to Tracking and Navigation", 2001,
s. 5.4.2). The study flies the same scenario with N seeds (each seed draws the world's
turbulence and every sensor's noise anew), takes the in-process loop's truth-aware log
columns (``nees``, ``att_err``, ``gyro_bias_err``) and reports the run-averaged NEES
against its two-sided 95 % band, the attitude error and the gyro-bias error in sigmas.

    python -m heli_sitl.studies.nav_study --world gps-typical --flights 20
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from autopilot.estimation.config import EstimatorConfig
from autopilot.estimation.ins import N_NAV
from autopilot.estimation.log import EST_LOG_COLUMNS
from autopilot.estimation.matched import matched
from heli_common.world.config import World


@dataclass(frozen=True)
class NavConsistency:
    world: str
    flights: int
    dof: int  # navigation states
    skip_s: float  # the start left out (the filter converging from its prior)
    nees_mean: float  # over flights and ticks
    band: tuple[float, float]  # 95 % band of the run-averaged NEES
    in_band: float  # fraction of ticks whose run-averaged NEES lies in the band
    att_rms_deg: tuple[float, float, float]  # true attitude error about body x, y, z
    gyro_bias_z_max: float  # the largest |error| / sigma of the final gyro bias estimate
    rms_45_120_m: float  # the controller's tracking error (truth), mean over flights

    @property
    def consistent(self) -> bool:
        return self.band[0] <= self.nees_mean <= self.band[1]

    def table(self) -> str:
        lo, hi = self.band
        return "\n".join([
            f"| {self.world}, {self.flights} flights | value |",
            "|---|---|",
            f"| NEES mean ({self.dof} states, after {self.skip_s:g} s) | {self.nees_mean:.2f} |",
            f"| 95 % band of the {self.flights}-run average | [{lo:.2f}, {hi:.2f}] |",
            f"| ticks with the run average in the band | {100 * self.in_band:.1f} % |",
            "| attitude error RMS x, y, z | " + ", ".join(f"{v:.3f}" for v in self.att_rms_deg) + " deg |",
            f"| final gyro bias error, largest over flights and axes | {self.gyro_bias_z_max:.2f} sigma |",
            f"| RMS [45, 120] (truth), mean | {self.rms_45_120_m:.4f} m |",
        ])  # fmt: skip


def consistency(
    world: str | World = "gps-typical", flights: int = 20, estimator: EstimatorConfig | None = None,
    match: bool = True, skip_s: float = 5.0, first_seed: int = 1,
) -> NavConsistency:  # fmt: skip
    """Fly the paper scenario ``flights`` times (seeds ``first_seed``...) in ``world`` on the
    navigation filter (tuned to the world's sensors when ``match``) and measure it."""
    from heli_sitl.api import simulate

    w = world if isinstance(world, World) else World.load(world)
    cfg = dataclasses.replace(estimator or EstimatorConfig(), attitude="ins")
    if match:
        cfg = matched(cfg, w.sensors)
    c = EST_LOG_COLUMNS
    nees, att, z_bias, rms = [], [], [], []
    for seed in range(first_seed, first_seed + flights):
        f = simulate(world=w, estimator=cfg, seed=seed)
        if f.record is None or f.metrics is None or f.record.est_log is None:
            raise RuntimeError(f"seed {seed}: the flight failed: {f.error}")
        log, t = f.record.est_log, f.record.t_s
        keep = t >= skip_s
        nees.append(log[keep, c.index("nees")])
        i = c.index("att_err_x")
        att.append(log[keep, i : i + 3])
        e = log[-1, c.index("gyro_bias_err_x") : c.index("gyro_bias_err_x") + 3]
        s = log[-1, c.index("sd_gyro_bias_x") : c.index("sd_gyro_bias_x") + 3]
        z_bias.append(float(np.max(np.abs(e / s))))
        rms.append(f.metrics.rms_45_m)
    avg = np.mean(np.vstack(nees), axis=0)
    lo, hi = (float(chi2.ppf(p, N_NAV * flights)) / flights for p in (0.025, 0.975))
    a = np.degrees(np.sqrt(np.mean(np.vstack(att) ** 2, axis=0)))
    return NavConsistency(
        world=w.name if hasattr(w, "name") else str(world), flights=flights, dof=N_NAV, skip_s=skip_s,
        nees_mean=float(np.mean(avg)), band=(lo, hi), in_band=float(np.mean((avg >= lo) & (avg <= hi))),
        att_rms_deg=(float(a[0]), float(a[1]), float(a[2])), gyro_bias_z_max=max(z_bias),
        rms_45_120_m=float(np.mean(rms)) if all(math.isfinite(r) for r in rms) else math.nan,
    )  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m heli_sitl.studies.nav_study",
                                description=__doc__.split("\n")[0])  # fmt: skip
    p.add_argument("--world", default="gps-typical")
    p.add_argument("--flights", type=int, default=20)
    p.add_argument("--no-match", action="store_true", help="the default (consumer) tuning, not the world's")
    a = p.parse_args(argv)
    print(consistency(a.world, a.flights, match=not a.no_match).table())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
