"""How much flying from sensors costs the paper flight: ``python -m heli_sitl.studies.sensor_study``.

Flies the paper scenario in-process (the same compiled loop as ``heli-sitl simulate``)
1. with each sensor preset of ``configs/world/``, printing the truth-based tracking error
   beside what the controller saw (reference - estimate) and the estimate's own error;
2. with a GPS whose white noise grows (no wander; the estimator told the noise it is
   given), whose slow Gauss-Markov wander grows (tau 60 s, + 0.3 m white), and whose
   latency grows (0.3 m white), each over several seeds, to find where RMS[45, 120]
   crosses 0.5 m;
and writes ``sensor_study.json`` and ``fig_sensor_thresholds.png`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from autopilot.estimation.config import EstimatorConfig
from autopilot.estimation.matched import matched
from autopilot.flight_metrics import FlightMetrics, window_value
from autopilot.scenario import Scenario
from heli_common.world.config import World
from heli_common.world.sensors import Baro, Gps, Sensors
from heli_sitl.engine.closed_loop import SimOptions, simulate

THRESHOLD_M = 0.5
PRESETS = (("gps-typical", None), ("imu-consumer", None), ("noisy", None), ("noisy", "noisy"))
NOISE_M = (0.1, 0.5, 1.0, 2.0, 3.0, 5.0, 7.5, 10.0, 15.0, 20.0)
LAG_S = (0.0, 0.1, 0.2, 0.5, 1.0, 1.5, 2.0)
WANDER_M = (0.0, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.1)


def fly(sc: Scenario, world: World, est: EstimatorConfig) -> dict[str, Any]:
    rec = simulate(sc, SimOptions(world=world, estimator=est))
    s, m = rec.summary(), FlightMetrics.of(rec)
    out = {
        "rms45_m": m.rms_45_m,
        "max10_m": m.max_err_after_10_s_m,
        "realtime_factor": s["realtime_factor"],
    }
    if "estimate" not in s:  # sensors off: the truth
        return out
    e = s["estimate"]
    return out | {
        "seen_rms45_m": window_value(e["rms_pos_err_seen_m"], 45.0),
        "est_rms45_m": window_value(e["rms_est_err_m"], 45.0),
        "gps_fixes": e["gps_fixes"],
        "mean_nis": e["mean_nis"],
    }


def _gps_world(seed: int, noise_m: float, lag_s: float, wander_m: float = 0.0) -> World:
    gps = Gps(on=True, rate_hz=5.0, lag_s=lag_s, noise_h_m=noise_m, noise_v_m=noise_m, vel_noise_m_s=0.05,
              wander_h_m=wander_m, wander_v_m=wander_m, wander_tau_s=60.0)  # fmt: skip
    sensors = Sensors(seed=seed, gps=gps, baro=Baro(on=True, noise_m=0.2))
    return World(name="gps-sweep", seed=seed, sensors=sensors)


def _crossing(xs: list[float], ys: list[float], level: float) -> float | None:
    """The first x where the piecewise-linear y(x) reaches ``level`` (None: never)."""
    for (x0, y0), (x1, y1) in zip(zip(xs, ys, strict=True), zip(xs[1:], ys[1:], strict=True), strict=False):
        if y0 < level <= y1:
            return x0 + (level - y0) * (x1 - x0) / (y1 - y0)
    return None


def sweep(sc: Scenario, seeds: int) -> dict[str, Any]:
    def mean_rms(est: EstimatorConfig, noise_m: float, lag_s: float, wander_m: float = 0.0) -> float:
        # each point's filter is told the GPS it is given (as a filter tuned from its
        # receiver's datasheet is): the per-axis filters through gps_pos_sigma_m, the
        # navigation filter through matched()
        rms = []
        for s in range(1, seeds + 1):
            world = _gps_world(s, noise_m, lag_s, wander_m)
            rms.append(fly(sc, world, matched(est, world.sensors))["rms45_m"])
        return float(np.mean(rms))

    vel = (0.1, 0.1, 0.1)
    noise = [mean_rms(EstimatorConfig(gps_pos_sigma_m=(n, n, n), gps_vel_sigma_m_s=vel), n, 0.1)
             for n in NOISE_M]  # fmt: skip
    lag_est = EstimatorConfig(gps_pos_sigma_m=(0.3, 0.3, 0.3), gps_vel_sigma_m_s=vel, buffer_s=2.5)
    lag = [mean_rms(lag_est, 0.3, lag) for lag in LAG_S]
    wander = [mean_rms(EstimatorConfig(), 0.3, 0.1, w) for w in WANDER_M]
    out: dict[str, Any] = {"seeds": seeds, "threshold_m": THRESHOLD_M}
    for key, xs, ys in (("noise_m", NOISE_M, noise), ("lag_s", LAG_S, lag), ("wander_m", WANDER_M, wander)):
        out[key] = list(xs)
        out[f"{key}_rms45_m"] = ys
        out[f"{key}_at_threshold"] = _crossing(list(xs), ys, THRESHOLD_M)
    return out


def plot(sw: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 3, figsize=(13, 4))
    panels = (("noise_m", "GPS white noise per axis [m] (100 ms lag)"),
              ("wander_m", "GPS wander sigma [m] (tau 60 s, + 0.3 m white)"),
              ("lag_s", "GPS latency [s] (0.3 m white noise)"))  # fmt: skip
    for a, (x, label) in zip(axs, panels, strict=True):
        a.plot(sw[x], sw[f"{x}_rms45_m"], "o-b")
        a.axhline(THRESHOLD_M, color="r", ls="--", lw=0.8)
        a.set_xlabel(label)
        a.set_ylabel("RMS 3-D error [45, 120] s [m]")
        a.grid(alpha=0.3)
    fig.suptitle(f"Paper flight from GPS + baro, mean of {sw['seeds']} seeds", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m heli_sitl.studies.sensor_study", description=__doc__)
    p.add_argument("--out", default="out/sensor_study")
    p.add_argument("--seeds", type=int, default=3)
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sc = Scenario.load("paper")
    simulate(sc, SimOptions(world=World.load("gps-typical"), duration_s=1.0))  # load the kernels
    rows = []
    base = fly(sc, World(), EstimatorConfig()) | {"preset": "truth (sensors off)", "estimator": "-"}
    print("| sensors | estimator | RMS[45,120] truth | max after 10 s | RMS[45,120] seen (ref - estimate) "
          "| RMS[45,120] estimate - truth | fixes accepted / rejected / resets | mean NIS |")
    print("|---|---|---|---|---|---|---|---|")
    for preset, est_name in PRESETS:
        est = EstimatorConfig.load(est_name) if est_name else EstimatorConfig()
        r = fly(sc, World.load(preset), est) | {"preset": preset, "estimator": est_name or "default"}
        rows.append(r)
        g = r["gps_fixes"]
        print(f"| {preset} | {r['estimator']} | {r['rms45_m']:.3f} | {r['max10_m']:.2f} "
              f"| {r['seen_rms45_m']:.3f} | {r['est_rms45_m']:.3f} "
              f"| {g['accepted']} / {g['rejected']} / {g['resets']} | {r['mean_nis']:.1f} |")
    print(f"| off | - | {base['rms45_m']:.4f} | {base['max10_m']:.2f} | | | | |")
    sw = sweep(sc, args.seeds)
    for key, what in (("noise_m", "GPS white noise per axis (100 ms lag)"),
                      ("wander_m", "GPS wander sigma (tau 60 s, + 0.3 m white, 100 ms lag)"),
                      ("lag_s", "GPS latency (0.3 m white)")):  # fmt: skip
        cross = sw[f"{key}_at_threshold"]
        where = "not reached" if cross is None else f"{cross:.3g}"
        pts = ", ".join(f"{x:g}: {r:.3f}" for x, r in zip(sw[key], sw[f"{key}_rms45_m"], strict=True))
        unit = key.split("_")[-1]
        print(f"{what}: RMS[45,120] reaches {THRESHOLD_M} m at {where} {unit}; RMS by value: {pts}")
    result = {"presets": rows, "off": base, "sweep": sw}
    (out / "sensor_study.json").write_text(json.dumps(result, indent=2) + "\n")
    plot(sw, out / "fig_sensor_thresholds.png")
    print(f"wrote {out / 'sensor_study.json'}, {out / 'fig_sensor_thresholds.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


