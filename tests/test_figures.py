"""Figures a newcomer can read: the campaign scatters say what each colour is and keep failed
flights apart from those that did not converge, a skewed histogram goes to a log axis and
says so, Fig 5 draws a level path level, Fig 11 says what its band is."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pyarrow as pa
import pytest

from autopilot.metrics import ref_column
from ground.plots import plot_estimate, plot_figures
from heli_sitl.studies.campaigns.report import plots
from heli_sitl.studies.campaigns.spec import CampaignSpec, Vary

METRICS = ("rms_10_m", "max_tilt_rad", "converged", "diverged")


@pytest.fixture
def drawn(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[[], list[Any]]]:
    """The figures drawn since the test began, kept open for inspection (the code under
    test closes each after saving it)."""
    close = plt.close
    monkeypatch.setattr(plt, "close", lambda *a, **k: None)
    before = set(plt.get_fignums())
    yield lambda: [plt.figure(n) for n in plt.get_fignums() if n not in before]
    close("all")


def _campaign(values: list[float]) -> tuple[CampaignSpec, pa.Table]:
    """Eight flights: two of each outcome (the failed ones with no metrics)."""
    spec = CampaignSpec(name="t", metrics=METRICS,
                        vary=(Vary("world.wind.speed_m_s", "grid", 0.0, 7.0, n=8),))  # fmt: skip
    failed = [False] * 6 + [True] * 2
    rows = {
        "sample_id": list(range(8)),
        "world.wind.speed_m_s": [float(i) for i in range(8)],
        "rms_10_m": [None if f else v for v, f in zip(values, failed, strict=True)],
        "max_tilt_rad": [None if f else 0.1 * (i + 1) for i, f in enumerate(failed)],
        "converged": [True, True, False, False, False, False, None, None],
        "diverged": [False, False, False, False, True, True, None, None],
        "failed": failed,
    }
    return spec, pa.table(rows)


def test_scatter_legend_names_every_outcome_and_keeps_failed_apart(
    tmp_path: Path, drawn: Callable[[], list[Any]]
) -> None:
    spec, t = _campaign([0.5, 0.6, 0.8, 1.0, 30.0, 40.0, 0.0, 0.0])
    plots(spec, t, tmp_path)
    scatter = next(f for f in drawn() if "against" in f.get_suptitle())
    (legend,) = scatter.legends
    labels = [x.get_text() for x in legend.get_texts()]
    assert len(labels) == 4
    for word, n in (("converged:", 2), ("did not converge", 2), ("diverged", 2), ("failed", 2)):
        (label,) = [s for s in labels if s.startswith(word)]
        assert f"({n})" in label, label
    assert "raised an error" in next(s for s in labels if s.startswith("failed"))
    # every outcome (failed and not converged too) differs from the others in colour and marker
    assert len({h.get_color() for h in legend.legend_handles}) == 4
    assert len({h.get_marker() for h in legend.legend_handles}) == 4
    # the failed flights are drawn (at their setting, on the bottom edge), not dropped
    ax = scatter.axes[0]
    xs = [list(line.get_xdata()) for line in ax.get_lines() if line.get_marker() == "x"]
    assert xs == [[6.0, 7.0]]


def test_a_histogram_spanning_four_decades_is_log_and_says_so(
    tmp_path: Path, drawn: Callable[[], list[Any]]
) -> None:
    spec, t = _campaign([1e-3, 1e-2, 0.1, 1.0, 10.0, 10.0, 0.0, 0.0])
    plots(spec, t, tmp_path)
    hist = next(f for f in drawn() if "flown" in f.get_suptitle())
    rms, tilt = hist.axes[:2]
    assert rms.get_xscale() == "log" and "log" in rms.get_title()
    assert "log" in hist.get_suptitle()
    # the bins are log-spaced: equal widths in log10
    edges = [p.get_x() for p in rms.patches] + [rms.patches[-1].get_x() + rms.patches[-1].get_width()]
    widths = np.diff(np.log10(edges))
    assert np.allclose(widths, widths[0])
    # 0.1 to 0.6: linear, no note
    assert tilt.get_xscale() == "linear" and "log" not in tilt.get_title()


def test_a_grid_map_marks_failed_flights_apart(tmp_path: Path, drawn: Callable[[], list[Any]]) -> None:
    spec = CampaignSpec(name="g", sampler="grid", metrics=METRICS,
                        vary=(Vary("servo.delay_s", "grid", 0.0, 1.0, n=3),
                              Vary("servo.tau_s", "grid", 0.0, 1.0, n=3)))  # fmt: skip
    a, b = (v.ravel().tolist() for v in np.meshgrid([0.0, 0.5, 1.0], [0.0, 0.5, 1.0]))
    failed = [i == 4 for i in range(9)]
    conv = [x + y < 1.0 for x, y in zip(a, b, strict=True)]
    t = pa.table({"servo.delay_s": a, "servo.tau_s": b, "failed": failed, "converged": conv,
                  "diverged": [x + y > 1.5 for x, y in zip(a, b, strict=True)],
                  "rms_10_m": [None if f else 0.1 for f in failed],
                  "max_tilt_rad": [None if f else 0.1 for f in failed]})  # fmt: skip
    files = plots(spec, t, tmp_path)
    assert tmp_path / "map.png" in files
    fmap = next(f for f in drawn() if "over the grid" in f.axes[0].get_title())
    labels = [x.get_text() for x in fmap.axes[0].get_legend().get_texts()]
    assert any(s.startswith("failed") and "(1)" in s for s in labels)
    assert any(s.startswith("did not converge") for s in labels)


def _flat_cols() -> dict[str, np.ndarray]:
    t = np.linspace(0.0, 10.0, 101)
    cols = {"t_s": t}
    for k, v in (("x_m", 20 * np.cos(t)), ("y_m", 10 * np.sin(t)), ("z_m", 20.0 + 0.01 * np.sin(3 * t)),
                 ("psi_rad", 0 * t), ("phi_rad", 0 * t), ("theta_rad", 0 * t)):  # fmt: skip
        cols[k], cols[ref_column(k)] = v, v
    cols["z_ref_m"] = np.full_like(t, 20.0)
    for k in ("theta_m_rad", "theta_t_rad", "eps_rad", "eta_rad"):
        cols[k] = 0 * t
    return cols


def test_fig5_draws_a_level_path_on_at_least_a_metre_of_height(
    tmp_path: Path, drawn: Callable[[], list[Any]]
) -> None:
    plot_figures(_flat_cols(), tmp_path, pitch_limits_rad=np.tile([-0.5, 0.5], (4, 1)))
    fig5 = next(f for f in drawn() if f.axes and f.axes[0].name == "3d")
    ax = fig5.axes[0]
    lo, hi = ax.get_zlim()
    assert hi - lo >= 1.0 and lo < 20.0 < hi
    assert np.diff(ax.get_xlim())[0] > 40.0  # a wide axis keeps its autoscale


def test_fig11_says_what_the_band_and_the_line_are(tmp_path: Path, drawn: Callable[[], list[Any]]) -> None:
    t = np.linspace(0.0, 10.0, 50)
    truth = np.zeros((50, 3))
    path = plot_estimate(t, truth, truth + 1.0, np.full((50, 3), 0.15), tmp_path)
    assert path.stat().st_size > 10_000
    (fig,) = drawn()
    caption = " ".join(x.get_text() for x in fig.texts)
    assert "2-sigma" in caption and "reports for itself" in caption and "estimate - truth" in caption
    labels = [x.get_text() for x in fig.axes[0].get_legend().get_texts()]
    assert any("own +-2 sigma" in s for s in labels) and any("estimate - truth" in s for s in labels)


def test_fig11b_draws_attitude_and_bias_errors_only_where_the_truth_is_known(tmp_path: Path) -> None:
    from ground.plots import ATTITUDE_FIGURE, plot_attitude_estimate

    t = np.linspace(0.0, 10.0, 101)
    e = np.column_stack([0.01 * np.sin(t)] * 3)
    sd = np.full((t.size, 3), 0.02)
    assert plot_attitude_estimate(t, np.full_like(e, np.nan), sd, e, sd, tmp_path) is None
    path = plot_attitude_estimate(t, e, sd, e, sd, tmp_path, title="t")
    assert path == tmp_path / ATTITUDE_FIGURE and path.stat().st_size > 10_000
