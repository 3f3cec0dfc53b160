"""The paper's Figs 5-8 from flight columns (run.csv names): path, position/yaw, attitude, pitches."""

from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only; never needs a display
import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt

from autopilot.metrics import ref_column

Cols = Mapping[str, npt.NDArray[np.float64]]
FIGURES = ("fig5_path3d.png", "fig6_position.png", "fig7_attitude.png", "fig8_controls.png",
           "fig9_error.png")


def read_csv_columns(path: Path) -> dict[str, npt.NDArray[np.float64]]:
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ValueError(f"{path}: empty CSV")
    header, data = rows[0], np.array(rows[1:], dtype=float).reshape(-1, len(rows[0]))
    return {h: data[:, i] for i, h in enumerate(header)}


def plot_figures(
    cols: Cols, out_dir: Path, title: str = "", pitch_limits_rad: npt.ArrayLike | None = None
) -> list[Path]:
    """Write the paper's Figs 5-8 and the 3-D error (Fig 9); returns their paths.
    ``pitch_limits_rad``: (4, 2) lower/upper limits drawn on Fig 8 (default: the airframe's)."""
    if pitch_limits_rad is None:
        from heli_common.vehicle.airframe import Airframe

        pitch_limits_rad = Airframe.load().limits.as_tuple()
    lim = np.asarray(pitch_limits_rad, dtype=float).reshape(4, 2)
    out_dir.mkdir(parents=True, exist_ok=True)
    t = cols["t_s"]
    paths = [out_dir / f for f in FIGURES]
    suffix = f" - {title}" if title else ""

    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.plot(cols["x_ref_m"], cols["y_ref_m"], cols["z_ref_m"], "k--", lw=1, label="command")
    ax.plot(cols["x_m"], cols["y_m"], cols["z_m"], "b", lw=1.2, label="helicopter")
    ax.set_xlabel("x north [m]")
    ax.set_ylabel("y west [m]")
    ax.set_zlabel("z up [m]")
    _min_span(ax, cols, PATH_MIN_SPAN_M)
    ax.set_title(f"Fig. 5: 3-D path (NWU){suffix}")
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, 1.0), fontsize=8, framealpha=0.6)
    fig.savefig(paths[0], dpi=110)
    plt.close(fig)

    _tracking_panels(paths[1], cols, (("x_m", "m"), ("y_m", "m"), ("z_m", "m"), ("psi_rad", "rad")),
                     f"Fig. 6: position and yaw vs command{suffix}", (8, 9))
    _tracking_panels(paths[2], cols, (("phi_rad", "rad"), ("theta_rad", "rad")),
                     f"Fig. 7: roll and pitch (FLU){suffix}", (8, 6))

    fig, axs = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    labels = {
        "theta_m": "main collective",
        "theta_t": "tail collective",
        "eps": "longitudinal cyclic",
        "eta": "lateral cyclic",
    }
    for i, (a, (key, label)) in enumerate(zip(axs, labels.items(), strict=True)):
        a.plot(t, cols[f"{key}_rad"], "b", lw=1.1)
        for bound in lim[i]:
            a.axhline(bound, color="r", ls=":", lw=1)  # the servo's limits
        a.set_ylabel(f"{key} [rad]")
        a.set_title(label, fontsize=9)
        a.grid(alpha=0.3)
    axs[0].set_title(f"Fig. 8: blade pitches, limits dotted{suffix}\nmain collective", fontsize=9)
    axs[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(paths[3], dpi=110)
    plt.close(fig)

    err = np.sqrt(sum((cols[k] - cols[ref_column(k)]) ** 2 for k in ("x_m", "y_m", "z_m")))
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.semilogy(t, np.maximum(err, 1e-6), "b", lw=1.1)
    ax.set_ylabel("|position error| [m]")
    ax.set_xlabel("t [s]")
    ax.set_title(f"Fig. 9: 3-D position error{suffix}")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(paths[4], dpi=110)
    plt.close(fig)
    return paths


#: Fig 5's smallest span per axis: autoscaling a level flight's few mm of height to the full
#: box would draw a flat path as a steep zig-zag
PATH_MIN_SPAN_M = 1.0


def _min_span(ax: Any, cols: Cols, span_m: float) -> None:
    """Widen each axis of a 3-D plot whose path and command span less than ``span_m``
    to ``span_m`` about their middle; wider axes keep matplotlib's autoscale."""
    for key, set_lim in (("x_m", ax.set_xlim), ("y_m", ax.set_ylim), ("z_m", ax.set_zlim)):
        v = np.concatenate([cols[key], cols[ref_column(key)]])
        v = v[np.isfinite(v)]
        if v.size and v.max() - v.min() < span_m:
            mid = 0.5 * (v.max() + v.min())
            set_lim(mid - 0.5 * span_m, mid + 0.5 * span_m)


def _tracking_panels(
    path: Path, cols: Cols, keys: tuple[tuple[str, str], ...], title: str, size: tuple[float, float]
) -> None:
    """One panel per (column, unit) against time: the command (dashed) where there is one."""
    t = cols["t_s"]
    fig, axs = plt.subplots(len(keys), 1, figsize=size, sharex=True)
    for a, (key, unit) in zip(axs, keys, strict=True):
        if ref_column(key) in cols:
            a.plot(t, cols[ref_column(key)], "k--", lw=1, label="command")
        a.plot(t, cols[key], "b", lw=1.1, label="actual")
        a.set_ylabel(f"{key.split('_', 1)[0]} [{unit}]")
        a.grid(alpha=0.3)
    # the legend above the first panel, beside the title: never over the data
    axs[0].legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=2, frameon=False, fontsize=8)
    axs[0].set_title(title, loc="left")
    axs[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


WORLD_FIGURE = "fig10_world.png"


def plot_world(
    t: npt.NDArray[np.float64], air_nwu_m_s: npt.NDArray[np.float64], commanded: npt.NDArray[np.float64],
    reached: npt.NDArray[np.float64], out_dir: Path, title: str = "",
) -> Path:  # fmt: skip
    """Fig 10: the air velocity (earth NWU) and each servo's command against the pitch it
    reached, for a flight in a world (``--world``)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / WORLD_FIGURE
    fig, axs = plt.subplots(5, 1, figsize=(8, 11), sharex=True)
    for i, (name, style) in enumerate((("north", "b"), ("west", "g"), ("up", "m"))):
        axs[0].plot(t, air_nwu_m_s[:, i], style, lw=0.9, label=name)
    axs[0].set_ylabel("air [m/s]")
    axs[0].legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=3, frameon=False, fontsize=8)
    for i, key in enumerate(("theta_m", "theta_t", "eps", "eta")):
        a = axs[i + 1]
        a.plot(t, commanded[:, i], "k--", lw=0.9, label="command")
        a.plot(t, reached[:, i], "b", lw=1.0, label="servo")
        a.set_ylabel(f"{key} [rad]")
        a.grid(alpha=0.3)
    axs[0].grid(alpha=0.3)
    axs[1].legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=2, frameon=False, fontsize=8)
    return _finish(fig, axs, path, "Fig. 10: air velocity, servo command vs position", title)


def _finish(fig: Any, axs: Any, path: Path, caption: str, title: str) -> Path:
    """Caption (with the run's title), time axis, layout, save, close."""
    suffix = f" - {title}" if title else ""
    fig.suptitle(f"{caption}{suffix}", fontsize=10)
    axs[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path



ESTIMATE_FIGURE = "fig11_estimate.png"
ESTIMATE_CAPTION = (
    "Grey band: +-2 x the position standard deviation the estimator reports for itself (its own 2-sigma\n"
    "uncertainty, not a tolerance); a consistent filter keeps the line inside it ~95 % of the time.\n"
    "Blue line: estimate - truth, the error the filter actually has. Bottom: its 3-D magnitude."
)


def plot_estimate(
    t: npt.NDArray[np.float64], truth_nwu_m: npt.NDArray[np.float64], est_nwu_m: npt.NDArray[np.float64],
    sd_nwu_m: npt.NDArray[np.float64], out_dir: Path, title: str = "",
) -> Path:  # fmt: skip
    """Fig 11, flying from sensors: per axis the estimate's error against the truth with the
    estimator's own +-2 sigma, and the 3-D estimate error. ``sd_nwu_m``: the filter's
    position standard deviations (the square roots of its covariance's diagonal)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / ESTIMATE_FIGURE
    fig, axs = plt.subplots(4, 1, figsize=(8, 10.6), sharex=True)
    err = est_nwu_m - truth_nwu_m
    for i, name in enumerate(("north", "west", "up")):
        a = axs[i]
        a.fill_between(t, -2 * sd_nwu_m[:, i], 2 * sd_nwu_m[:, i], color="0.85",
                       label="band: the filter's own +-2 sigma (its claimed uncertainty)")  # fmt: skip
        a.plot(t, err[:, i], "b", lw=0.8, label="line: estimate - truth (its actual error)")
        a.set_ylabel(f"{name} [m]")
        a.grid(alpha=0.3)
    axs[0].legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=2, frameon=False, fontsize=8)
    axs[3].plot(t, np.linalg.norm(err, axis=1), "k", lw=0.8)
    axs[3].set_ylabel("|estimate - truth| [m]")
    axs[3].grid(alpha=0.3)
    suffix = f" - {title}" if title else ""
    fig.suptitle(f"Fig. 11: position estimate vs truth{suffix}", fontsize=10)
    axs[-1].set_xlabel("t [s]")
    # the band is what the filter believes, not a tolerance: a newcomer reads a narrow band
    # under a wide error as a bug in the figure unless told that the gap is the finding
    fig.text(0.01, 0.005, ESTIMATE_CAPTION, fontsize=8, va="bottom", ha="left")
    fig.tight_layout(rect=(0.0, 0.06, 1.0, 1.0))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


ATTITUDE_FIGURE = "fig11b_attitude.png"


def plot_attitude_estimate(
    t: npt.NDArray[np.float64], att_err_rad: npt.NDArray[np.float64], sd_att_rad: npt.NDArray[np.float64],
    gyro_bias_err: npt.NDArray[np.float64], sd_gyro_bias: npt.NDArray[np.float64], out_dir: Path,
    title: str = "",
) -> Path | None:  # fmt: skip
    """Fig 11b, the navigation filter: its true attitude error about body x, y, z and its
    gyro-bias error, each with the filter's own +-2 sigma (est.csv's att_err, sd_att,
    gyro_bias_err, sd_gyro_bias). None when the log has no truth (over processes, or the
    attitude source)."""
    if not np.any(np.isfinite(att_err_rad)):
        return None
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / ATTITUDE_FIGURE
    fig, axs = plt.subplots(3, 2, figsize=(11, 7.5), sharex=True)
    for i, axis in enumerate("xyz"):
        for col, (err, sd, unit, what) in enumerate((
            (att_err_rad, sd_att_rad, "deg", "attitude error"),
            (gyro_bias_err, sd_gyro_bias, "deg/s", "gyro bias error"),
        )):  # fmt: skip
            a = axs[i, col]
            a.fill_between(t, -2 * np.degrees(sd[:, i]), 2 * np.degrees(sd[:, i]), color="0.85",
                           label="the filter's own +-2 sigma")  # fmt: skip
            a.plot(t, np.degrees(err[:, i]), "b", lw=0.8, label="truth - estimate")
            a.set_ylabel(f"{what} {axis} [{unit}]")
            a.grid(alpha=0.3)
    axs[0, 0].legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, frameon=False, fontsize=8)
    for a in axs[-1]:
        a.set_xlabel("t [s]")
    suffix = f" - {title}" if title else ""
    fig.suptitle(f"Fig. 11b: the navigation filter's attitude and gyro bias vs truth{suffix}", fontsize=10)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


ROTOR_FIGURE = "fig12_rotor.png"


def plot_rotor(cols: dict[str, npt.NDArray[np.float64]], out_dir: Path, title: str = "") -> Path | None:
    """Fig 12, on the rotor plant: rotor speed, the governor's throttle, and the tip-path
    plane's flapping beside the cyclic that commands it (run.csv's rotor columns). None
    (nothing drawn) for a flight without them."""
    if "omega_rad_s" not in cols:
        return None
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / ROTOR_FIGURE
    t = cols["t_s"]
    fig, axs = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    axs[0].plot(t, cols["omega_rad_s"], "b", lw=0.9)
    axs[0].set_ylabel("rotor speed [rad/s]")
    axs[1].plot(t, cols["throttle"], "m", lw=0.9)
    axs[1].set_ylabel("throttle [0-1]")
    for a, flap, cyc, name in (
        (axs[2], "a1_rad", "eps_rad", "longitudinal"),
        (axs[3], "b1_rad", "eta_rad", "lateral"),
    ):
        a.plot(t, cols[cyc], "k--", lw=0.8, label=f"cyclic {cyc.removesuffix('_rad')}")
        a.plot(t, cols[flap], "b", lw=0.9, label=f"flapping {flap.removesuffix('_rad')}")
        a.set_ylabel(f"{name} [rad]")
        a.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=2, frameon=False, fontsize=8)
    for a in axs:
        a.grid(alpha=0.3)
    return _finish(fig, axs, path, "Fig. 12: rotor speed, throttle, flapping", title)
