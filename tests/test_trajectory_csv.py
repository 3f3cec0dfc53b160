"""A trajectory from a CSV table (autopilot.trajectory.csv_table): the paper's helix sampled
at 10 Hz and rebuilt from the table, continuity in acceleration across rows, the bad tables
refused with their line and row, and the scenario file's ``kind = "csv"``, flown."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from autopilot.metrics import window_rms_m
from autopilot.scenario import Scenario
from autopilot.trajectory import CsvTrajectory, trajectory_from_csv, trajectory_from_table
from autopilot.trajectory.analytic import PaperSpiralCircle
from autopilot.trajectory.csv_table import ACCELERATION, POSITION, VELOCITY
from heli_common.config import CONFIG_DIR, ConfigError
from heli_common.state import PHI, THETA
from heli_sitl.engine.closed_loop import simulate

# the paper's circle (10 m, 80 s), climbing at 0.5 m/s all along: smooth, every axis moving
HELIX = PaperSpiralCircle(climb_end_s=80.0, duration_s=80.0)
ROWS_S = np.arange(0.0, 80.0 + 1e-9, 0.1)  # 10 Hz
BETWEEN_S = ROWS_S[:-1] + 0.05  # midway between rows: where interpolation errs most
ALL = (*POSITION, *VELOCITY, *ACCELERATION)


def write_table(path: Path, t: np.ndarray, rows: np.ndarray, names: tuple[str, ...]) -> Path:
    """t_s and the named columns of ``rows`` (the reference layout, pos | vel | acc), lossless."""
    cols = [ALL.index(n) for n in names]
    lines = [",".join(("t_s", *names))]
    lines += [",".join(repr(float(v)) for v in (tk, *r[cols])) for tk, r in zip(t, rows, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


def helix_table(tmp_path: Path, names: tuple[str, ...]) -> CsvTrajectory:
    return trajectory_from_csv(write_table(tmp_path / "helix.csv", ROWS_S, HELIX.sample(ROWS_S), names))


def max_err(traj: CsvTrajectory, t: np.ndarray) -> tuple[float, float, float]:
    e = np.abs(traj.sample(t) - HELIX.sample(t))
    return float(e[:, 0:3].max()), float(e[:, 3:6].max()), float(e[:, 6:9].max())


# ------------------------------------------------------------------------------ fidelity

# (columns, largest error midway between rows [m, m/s, m/s^2]), 2-3x the measured:
# 9.8e-10, 1.3e-8, 7.1e-7 position only; 1.1e-8, 1.5e-7, 1.7e-5 with velocity (at the two
# ends, where the least-jerk spline's zero end jerk is not the helix's); 7e-15, 1.7e-13,
# 1.5e-13 with every derivative (roundoff: each quintic is the helix's Hermite interpolant)
FIDELITY = {
    "position": (POSITION, (2.5e-9, 3e-8, 2e-6)),
    "velocity": ((*POSITION, *VELOCITY), (2.5e-8, 4e-7, 4e-5)),
    "acceleration": (ALL, (3e-14, 5e-13, 5e-13)),
}


@pytest.mark.parametrize("given", list(FIDELITY))
def test_a_sampled_helix_is_rebuilt_between_its_rows(tmp_path: Path, given: str) -> None:
    names, (tol_pos, tol_vel, tol_acc) = FIDELITY[given]
    traj = helix_table(tmp_path, names)
    assert traj.duration_s == 80.0
    pos, vel, acc = max_err(traj, BETWEEN_S)
    assert pos < tol_pos and vel < tol_vel and acc < tol_acc, (pos, vel, acc)
    # through every row exactly, and through its derivatives where the table gives them
    at_rows = traj.sample(ROWS_S)
    want = HELIX.sample(ROWS_S)
    given_cols = [ALL.index(n) for n in names]
    np.testing.assert_allclose(at_rows[:, given_cols], want[:, given_cols], rtol=0.0, atol=5e-13)


def test_away_from_the_ends_velocity_columns_make_it_exact(tmp_path: Path) -> None:
    """Inside, the least-jerk quintic is the helix to roundoff (the ends' error dies away
    within a few rows: measured 7e-15 m, 1.5e-13 m/s, 1.1e-12 m/s^2 from 5 s in); the
    cubic's acceleration is not (measured 1.6e-7 m/s^2)."""
    inner = BETWEEN_S[(BETWEEN_S > 5.0) & (BETWEEN_S < 75.0)]
    pos, vel, acc = max_err(helix_table(tmp_path, (*POSITION, *VELOCITY)), inner)
    assert pos < 3e-14 and vel < 5e-13 and acc < 3e-12, (pos, vel, acc)
    assert max_err(helix_table(tmp_path, POSITION), inner)[2] > 5e-8


@pytest.mark.parametrize("given", list(FIDELITY))
def test_velocity_and_acceleration_are_the_exact_derivatives(tmp_path: Path, given: str) -> None:
    traj = helix_table(tmp_path, FIDELITY[given][0])
    dt = 1e-4
    t = np.arange(0.013, 79.9, 0.37)  # off the rows
    ahead, here, behind = traj.sample(t + dt), traj.sample(t), traj.sample(t - dt)
    # central differences: error dt^2 / 6 times the next derivative (< 0.01 here) and the
    # roundoff of the difference (measured 2.4e-10 at most)
    np.testing.assert_allclose((ahead[:, 0:6] - behind[:, 0:6]) / (2 * dt), here[:, 3:9], rtol=0, atol=1e-9)


def random_table(seed: int, n: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Uneven times and rough data: a spline that were not C2 would show it here."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.2, 2.0, n)) - 0.2
    return t, rng.normal(0.0, 3.0, (n, 3)), rng.normal(0.0, 2.0, (n, 3)), rng.normal(0.0, 1.0, (n, 3))


@pytest.mark.parametrize("given", ["position", "velocity", "acceleration"])
def test_acceleration_is_continuous_across_rows(given: str) -> None:
    t, p, v, a = random_table(7)
    traj = CsvTrajectory(t, p, v if given != "position" else None, a if given == "acceleration" else None)
    inner = t[1:-1]
    left = traj.sample(np.nextafter(inner, -np.inf))
    right = traj.sample(np.nextafter(inner, np.inf))
    assert np.abs(right[:, 6:9]).max() > 0.5  # a real acceleration at the rows (measured 2.2 to 322)
    np.testing.assert_allclose(left, right, rtol=0.0, atol=1e-9)


def test_velocity_without_acceleration_has_the_least_jerk() -> None:
    """Jerk continuous at the rows and zero at both ends (the variational conditions of the
    least integral of squared jerk); the quintic through given accelerations has neither."""
    t, p, v, a = random_table(11)

    def jerk(traj: CsvTrajectory, tk: np.ndarray, side: float) -> np.ndarray:
        dt = 1e-6 * side
        return np.asarray((traj.sample(tk + dt)[:, 6:9] - traj.sample(tk)[:, 6:9]) / dt)

    least = CsvTrajectory(t, p, v)
    inner = t[1:-1]
    scale = np.abs(jerk(least, inner, 1.0)).max()  # measured 4.6e3 m/s^3 (rough data)
    assert scale > 100.0
    # one-sided differences: error dt / 2 times the snap (measured 1.3e-5 and 8e-8 of scale)
    np.testing.assert_allclose(jerk(least, inner, -1.0), jerk(least, inner, 1.0), rtol=0.0, atol=4e-5 * scale)
    assert np.abs(jerk(least, t[:1], 1.0)).max() < 3e-7 * scale
    assert np.abs(jerk(least, t[-1:], -1.0)).max() < 3e-7 * scale
    given = CsvTrajectory(t, p, v, a)
    assert np.abs(jerk(given, inner, -1.0) - jerk(given, inner, 1.0)).max() > 1.0 * scale  # measured 3.7


def test_before_and_after_the_table_it_holds_with_zero_derivatives() -> None:
    t, p, v, a = random_table(3)
    traj = CsvTrajectory(t + 2.0, p, v, a)  # the first row at 2 s
    out = traj.sample([0.0, 1.0, traj.duration_s + 0.5, traj.duration_s + 100.0])
    # the end rows' positions (the pieces there evaluated at their ends: to roundoff)
    np.testing.assert_array_equal(out[:2, 0:3], np.tile(traj.sample(t[0] + 2.0)[0, 0:3], (2, 1)))
    np.testing.assert_array_equal(out[2:, 0:3], np.tile(traj.sample(traj.duration_s)[0, 0:3], (2, 1)))
    np.testing.assert_allclose(out[:, 0:3], [p[0], p[0], p[-1], p[-1]], rtol=0.0, atol=1e-12)
    assert np.all(out[:, 3:9] == 0.0)
    assert traj.sample(5.0).shape == (1, 9)  # a scalar time is a one-row array, as for every kind
    for given in (CsvTrajectory(t, p), CsvTrajectory(t, p, v), traj):
        for tk in (-1.0, 0.0, float(t[0]), 3.3, float(t[5]), given.duration_s, given.duration_s + 1.0):
            np.testing.assert_allclose(given.evaluate_row(tk), given.sample(tk)[0], rtol=0.0, atol=1e-12)


def test_yaw_is_carried_not_flown(tmp_path: Path) -> None:
    f = tmp_path / "yaw.csv"
    f.write_text("t_s,x_m,y_m,z_m,yaw_rad\n0,0,0,1,3.0\n1,1,0,1,-3.0\n2,2,0,1,-3.0\n")
    traj = trajectory_from_csv(f)
    assert traj.has_yaw
    # across +-pi the short way: halfway from 3.0 to -3.0 (= 3.283) is 3.142 = -3.142
    mid = float(traj.yaw_nwu_rad(0.5)[0])
    assert abs(math.remainder(mid - math.pi, 2 * math.pi)) < 1e-12
    assert np.isnan(CsvTrajectory([0, 1], [[0, 0, 1]] * 2).yaw_nwu_rad([0.0, 1.0])).all()
    np.testing.assert_array_equal(traj.sample([0.5]), CsvTrajectory([0, 1, 2], traj.pos_nwu_m).sample([0.5]))


# ------------------------------------------------------------------------------ bad tables

GOOD = "t_s,x_m,y_m,z_m\n0,0,0,1\n1,1,0,1\n2,2,0,1\n"


@pytest.mark.parametrize(
    ("text", "where", "want"),
    [
        (GOOD.replace("2,2,0,1", "0.5,2,0,1"), "line 4 (data row 3)",
         "t_s = 0.5 s goes back from the row before (1.0 s)"),
        (GOOD.replace("2,2,0,1", "1,2,0,1"), "line 4 (data row 3)", "t_s = 1.0 s repeats the row before"),
        (GOOD.replace("1,1,0,1", "1,nan,0,1"), "line 3 (data row 2)", "x_m = nan is not a finite number"),
        (GOOD.replace("1,1,0,1", "1,1,-inf,1"), "line 3 (data row 2)", "y_m = -inf is not a finite number"),
        (GOOD.replace("1,1,0,1", "1,1,0,one"), "line 3 (data row 2)", "z_m is not a number: 'one'"),
        (GOOD.replace("1,1,0,1", "1,,0,1"), "line 3 (data row 2)", "x_m is empty"),
        (GOOD.replace("1,1,0,1", "1,1,0"), "line 3 (data row 2)",
         "expected 4 cells (t_s, x_m, y_m, z_m), got 3"),
        (GOOD.replace("0,0,0,1", "-1,0,0,1"), "line 2 (data row 1)", "times start at t_s >= 0"),
        # comments and blank lines count as lines, not as rows
        ("# a box\n\n" + GOOD.replace("2,2,0,1", "0,2,0,1"), "line 6 (data row 3)", "goes back"),
        ("t_s,x_m,y_m,z_m\n0,0,0,1\n", "", "1 data row(s) (last line 2); a trajectory needs at least 2"),
        ("t_s,x_m,y_m\n0,0,0\n1,1,0\n", "line 1", "missing column(s) ['z_m']; required: t_s, x_m, y_m, z_m"),
        (
            GOOD.replace("z_m", "z_m,speed").replace("1\n", "1,0\n"),
            "line 1",
            "unknown column(s) ['speed']; accepted: t_s, x_m, y_m, z_m, vx_m_s, vy_m_s, vz_m_s, "
            "ax_m_s2, ay_m_s2, az_m_s2, yaw_rad",
        ),
        ("t_s,x_m,y_m,z_m,x_m\n", "line 1", "column(s) ['x_m'] named more than once"),
        ("t_s,x_m,y_m,z_m,vx_m_s\n", "line 1",
         "velocity needs all of vx_m_s, vy_m_s, vz_m_s (got only vx_m_s)"),
        ("t_s,x_m,y_m,z_m,ax_m_s2,ay_m_s2,az_m_s2\n", "line 1", "acceleration columns need the velocity"),
        ("# only a comment\n", "", "empty: expected a header row"),
    ],
    ids=[
        "backwards", "repeated", "nan", "inf", "not-a-number", "empty-cell", "short-row", "negative-start",
        "comments", "one-row", "missing-column", "unknown-column", "twice", "part-velocity",
        "acc-without-vel", "empty",
    ],
)  # fmt: skip
def test_a_bad_table_is_refused_with_its_line_and_row(
    tmp_path: Path, text: str, where: str, want: str
) -> None:
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(ConfigError) as exc:
        trajectory_from_csv(f)
    msg = str(exc.value)
    assert msg.startswith(f"{f}: {where}"), msg
    assert want in msg, msg


def test_a_missing_table_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope\.csv: no such trajectory table"):
        trajectory_from_csv(tmp_path / "nope.csv")


def test_names_are_case_insensitive_in_any_order_and_a_bom_is_ignored(tmp_path: Path) -> None:
    f = tmp_path / "excel.csv"
    f.write_text("\ufeffZ_M, T_s ,x_m,y_m\n1,0,0,0\n1,1,1,0\n1,2,2,0\n", encoding="utf-8")
    traj = trajectory_from_csv(f)
    np.testing.assert_array_equal(traj.t_s, [0.0, 1.0, 2.0])
    np.testing.assert_array_equal(traj.pos_nwu_m[:, 0], [0.0, 1.0, 2.0])
    np.testing.assert_array_equal(traj.pos_nwu_m[:, 2], [1.0, 1.0, 1.0])


# ------------------------------------------------------------------------------ scenario files

SCENARIO = (CONFIG_DIR / "scenario_paper.toml").read_text()
PAPER_TRAJECTORY = SCENARIO[SCENARIO.index("[trajectory]") : SCENARIO.index("[initial_state]")]


@pytest.fixture
def scenario_dir(tmp_path: Path) -> Path:
    for f in ("xcell60.toml", "gains_paper.toml"):
        shutil.copy(CONFIG_DIR / f, tmp_path / f)
    (tmp_path / "tables").mkdir()
    write_table(tmp_path / "tables" / "helix.csv", ROWS_S, HELIX.sample(ROWS_S), POSITION)
    return tmp_path


def scenario_with(d: Path, trajectory: str) -> Path:
    p = d / "scenario_mine.toml"
    p.write_text(SCENARIO.replace(PAPER_TRAJECTORY, trajectory + "\n\n"))
    return p


def test_a_scenario_names_its_table_relative_to_its_own_directory(
    scenario_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(scenario_dir / "tables")  # not where the path starts
    sc = Scenario.load(scenario_with(scenario_dir, '[trajectory]\nkind = "csv"\npath = "tables/helix.csv"'))
    assert isinstance(sc.trajectory, CsvTrajectory)
    direct = trajectory_from_csv(scenario_dir / "tables" / "helix.csv")
    np.testing.assert_array_equal(sc.trajectory.sample(BETWEEN_S), direct.sample(BETWEEN_S))
    # an absolute path is taken as it is
    absolute = (scenario_dir / "tables" / "helix.csv").resolve()
    sc = Scenario.load(scenario_with(scenario_dir, f'[trajectory]\nkind = "csv"\npath = "{absolute}"'))
    assert sc.trajectory.duration_s == 80.0


@pytest.mark.parametrize(
    ("trajectory", "want"),
    [
        ('kind = "csv"\npath = "tables/nope.csv"', "trajectory.path: {d}/tables/nope.csv: no such file"),
        ('kind = "csv"', "trajectory.path: expected the table's file name, got None"),
        ('kind = "csv"\npath = "tables/helix.csv"\nradius_m = 3.0',
         "unknown key(s) ['radius_m'] for kind = 'csv'"),
        ('kind = "csv"\npath = "tables/bad.csv"',
         "trajectory.path: {d}/tables/bad.csv: line 3 (data row 2): x_m = nan"),
        ('kind = "spiral"', "(or \"csv\", samples from a file: kind = \"csv\" with path = \"table.csv\")"),
    ],
    ids=["no-file", "no-path", "extra-key", "bad-table", "kinds"],
)
def test_scenario_errors_name_the_scenario_and_the_table(
    scenario_dir: Path, trajectory: str, want: str
) -> None:
    (scenario_dir / "tables" / "bad.csv").write_text(GOOD.replace("1,1,0,1", "1,nan,0,1"))
    p = scenario_with(scenario_dir, "[trajectory]\n" + trajectory)
    with pytest.raises(ConfigError) as exc:
        Scenario.load(p)
    msg = str(exc.value)
    assert msg.startswith(f"{p}: trajectory"), msg
    assert want.format(d=scenario_dir) in msg, msg


def test_the_factory_takes_the_directory_it_is_given(scenario_dir: Path) -> None:
    table = {"kind": "csv", "path": "helix.csv"}
    traj = trajectory_from_table(table, "elsewhere/scenario.toml", scenario_dir / "tables")
    assert isinstance(traj, CsvTrajectory) and traj.duration_s == 80.0


# ------------------------------------------------------------------------------ the example, flown

# RMS 3-D position error [m] per error window ([0, 11] the start's drift and the climb,
# [11, 71] the box, [71, 80] the descent), measured with the paper's TLC (pseudo
# feedforward, 100 Hz) on the paper's plant when the example was made
MEASURED_RMS_M = (0.2658, 0.1722, 0.1491)


def test_the_example_starts_at_rest_on_its_first_row_and_stays_gentle() -> None:
    sc = Scenario.load("csv_example")
    traj = sc.trajectory
    assert isinstance(traj, CsvTrajectory) and traj.has_yaw
    assert traj.duration_s == sc.run.duration_s == 80.0
    t = np.arange(0.0, 80.0 + 1e-9, 0.01)
    s = traj.sample(t)
    np.testing.assert_array_equal(s[0, 0:3], sc.initial.pos_nwu_m)
    assert np.all(s[0, 3:9] == 0.0) and np.all(s[-1, 3:9] == 0.0)
    assert np.linalg.norm(s[:, 3:6], axis=1).max() == pytest.approx(1.5625, abs=1e-5)  # 1.875 * 10 m / 12 s
    assert np.linalg.norm(s[:, 6:9], axis=1).max() < 0.5
    np.testing.assert_allclose(s[:, 0:3].max(axis=0), [13.0, 7.0, 6.0], atol=1e-6)  # the box's corners
    np.testing.assert_allclose(s[:, 0:3].min(axis=0), [3.0, -3.0, 3.0], atol=1e-6)


def test_the_example_flies_with_the_paper_tlc() -> None:
    sc = Scenario.load("csv_example")
    rec = simulate(sc)
    assert rec.t_s[-1] == pytest.approx(80.0) and np.all(np.isfinite(rec.x))
    tilt = np.arccos(np.cos(rec.x[:, PHI]) * np.cos(rec.x[:, THETA]))
    assert tilt.max() < 0.13  # measured 0.088 rad
    assert rec.pos_err_m.max() < 0.5  # measured 0.41 m, the start's drift
    for (t0, t1), measured in zip(sc.run.error_windows_s, MEASURED_RMS_M, strict=True):
        assert 0.67 * measured <= window_rms_m(rec, t0, t1) <= 1.5 * measured
