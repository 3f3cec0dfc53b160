"""A newcomer's first hour, each stumble seen on a fresh clone and mended: one trajectory
schema for every reader (the plain t,x,y,z header, the API's SI names, a run.csv flown back),
a trajectory flown from its own first point, a scenario copied out of configs/, global
options before the command, an exit status printed as a word, and `up` saying what it wrote."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import heli_sitl as hs
from autopilot.metrics import CSV_HEADER, LEGACY_CSV_HEADER
from autopilot.scenario import Scenario
from autopilot.trajectory import trajectory_from_csv
from ground import files
from ground.cli import build_parser
from ground.plots import read_csv_columns
from heli_common.config import CONFIG_DIR, ConfigError
from heli_common.state import EPS, ETA, P_X, Q_Y, R_Z, THETA_M, THETA_T, U_F, V_L, W_U, X_N, Z_U
from heli_sitl.launch.demo import _written

ROOT = Path(__file__).resolve().parent.parent
LINE = "0,0,0,5\n10,5,0,5\n20,5,5,5\n"


def _table(tmp_path: Path, header: str, body: str = LINE, name: str = "line.csv") -> Path:
    p = tmp_path / name
    p.write_text(f"{header}\n{body}")
    return p


def test_the_plain_and_the_si_header_are_one_table_for_every_reader(tmp_path: Path) -> None:
    plain = _table(tmp_path, "t,x,y,z", name="plain.csv")
    si = _table(tmp_path, "t_s,x_m,y_m,z_m", name="si.csv")
    t = np.linspace(0.0, 20.0, 41)
    np.testing.assert_array_equal(trajectory_from_csv(plain).sample(t), trajectory_from_csv(si).sample(t))
    a, b = files.read_trajectory_csv(plain), files.read_trajectory_csv(si)
    np.testing.assert_array_equal(a.t_s, b.t_s)
    np.testing.assert_array_equal(a.pos_nwu_m, b.pos_nwu_m)
    # the ground station uploads positions (the vehicle splines them): velocities are refused
    vel = _table(tmp_path, "t_s,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s", "0,0,0,5,0,0,0\n10,5,0,5,0,0,0\n", "v.csv")
    with pytest.raises(files.FileFormatError, match="the vehicle splines positions"):
        files.read_trajectory_csv(vel)
    typo = _table(tmp_path, "t,x,y,zz", name="typo.csv")
    with pytest.raises(ConfigError, match=r"unknown column\(s\) \['zz'\]"):
        trajectory_from_csv(typo)


def test_a_run_csv_flies_back(tmp_path: Path) -> None:
    """A flight's record is a trajectory table: its t,x,y,z (the flown truth) are read, the
    rest of its columns ignored; it flies again (from its own first point)."""
    first = hs.simulate(duration_s=30.0)
    assert first.record is not None
    run_csv = tmp_path / "run.csv"
    first.record.write_csv(run_csv)
    traj = trajectory_from_csv(run_csv)
    assert traj.duration_s == pytest.approx(30.0)
    np.testing.assert_allclose(traj.sample(np.array([12.34]))[0, 0:3],
                               first.record.x[1234, X_N : Z_U + 1], atol=2e-6)  # fmt: skip
    again = hs.simulate(trajectory=run_csv)
    assert again.status is hs.ExitStatus.COMPLETED and again.metrics is not None
    # deterministic, pinned: its first seconds are the first flight's own convergence from
    # 5.2 m off, which a spline through positions alone follows less closely than the spiral
    assert again.metrics.rms_10_m == pytest.approx(0.15169333922, rel=1e-6), again.metrics.rms_m
    assert files.read_trajectory_csv(run_csv).t_s.size == 3001  # heli-ground fly's reader
    cmd = [sys.executable, "-m", "heli_sitl.cli", "simulate", "--trajectory", str(run_csv), "--out",
           str(tmp_path / "cli")]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"[10-30] s {again.metrics.rms_10_m:.4f} m" in done.stdout, done.stdout  # the API's flight
    # one schema: run.csv's columns are the API's (to_pandas, Parquet), by name and value
    api, csv_cols = first.columns(), read_csv_columns(run_csv)
    assert list(csv_cols) == list(CSV_HEADER) and set(CSV_HEADER) <= set(api)
    for name in CSV_HEADER:
        want = np.unwrap(api[name]) if name == "psi_rad" else api[name]
        np.testing.assert_allclose(csv_cols[name], want, rtol=1e-8, atol=1e-12, err_msg=name)
    # a run.csv from before the one schema (t, x, ..., x_cmd) still flies back
    legacy = tmp_path / "legacy.csv"
    rows = [[0.0] * 17, [10.0] + [2.0] * 16]  # t, then x, y, z and the rest
    legacy.write_text("\n".join(",".join(map(str, r)) for r in [LEGACY_CSV_HEADER, *rows]) + "\n")
    np.testing.assert_allclose(trajectory_from_csv(legacy).sample(np.array([10.0]))[0, 0:3], [2.0, 2.0, 2.0])


def test_a_trajectory_is_flown_from_its_own_first_point(tmp_path: Path) -> None:
    """Before, the paper scenario's initial state (5.2 m off its spiral) was kept: this table's
    flight started 5.9 m from its first row, and RMS [0, 20] was 1.55 m. Now it starts on it,
    level, with the table's velocity and heading."""
    moving = _table(tmp_path, "t,x,y,z", "0,0,0,5\n1,1,1,5\n2,2,2,5\n20,20,20,5\n", "moving.csv")
    f = hs.simulate(trajectory=_table(tmp_path, "t,x,y,z"))
    assert f.record is not None and f.metrics is not None
    np.testing.assert_array_equal(f.record.x[0, X_N : Z_U + 1], [0.0, 0.0, 5.0])
    assert f.metrics.rms_0_m < 0.3, f.metrics.rms_m  # 0.237 m measured (the spline's own start)
    sc = Scenario.load("paper").flying(trajectory_from_csv(moving))
    assert sc.initial.euler_rad[2] == pytest.approx(math.atan2(1.0, 1.0))  # heading along the path
    v = sc.trajectory.sample(np.array([0.0]))[0, 3:6]
    body = np.array(sc.initial.vel_flu_m_s)
    assert body[0] == pytest.approx(math.hypot(v[0], v[1])) and abs(body[1]) < 1e-12
    out = tmp_path / "cli"
    cmd = [sys.executable, "-m", "heli_sitl.cli", "simulate", "--trajectory", str(moving), "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "\r" not in done.stderr  # no progress bar where stderr is not a terminal (a log)
    g = hs.simulate(trajectory=moving)
    assert g.metrics is not None
    assert f"[0-20] s {g.metrics.rms_0_m:.4f} m" in done.stdout, done.stdout  # the API's flight


def test_a_scenario_copied_out_of_configs_still_finds_its_airframe_and_gains(tmp_path: Path) -> None:
    mine = tmp_path / "mine.toml"
    shutil.copy(CONFIG_DIR / "scenario_paper.toml", mine)
    assert Scenario.load(mine).airframe == Scenario.load("paper").airframe
    assert Scenario.load(mine).gains == Scenario.load("paper").gains
    (tmp_path / "xcell60.toml").write_text("not a table [")  # a file beside it wins, and is read
    with pytest.raises(ConfigError, match=r"xcell60\.toml"):
        Scenario.load(mine)


@pytest.mark.parametrize("argv", [
    ["--instance", "1", "params", "get", "X"], ["params", "get", "X", "--instance", "1"],
    ["--instance", "2", "params", "get", "X", "--instance", "1"],
])  # fmt: skip
def test_heli_ground_takes_its_options_before_or_after_the_command(argv: list[str]) -> None:
    args = build_parser().parse_args(argv)
    assert args.instance == 1 and args.connect_timeout_s == 30.0 and args.name == "X"


def test_an_exit_status_prints_as_a_word() -> None:
    assert f"{hs.ExitStatus.COMPLETED}" == "completed" and str(hs.ExitStatus.LOST) == "lost"


def test_a_stopped_up_says_what_it_wrote(tmp_path: Path) -> None:
    assert _written(None).startswith("nothing written (--out DIR keeps")
    assert _written(tmp_path) == f"nothing in {tmp_path}"
    (tmp_path / "logs").mkdir()
    (tmp_path / "run.csv").write_text("t\n")
    assert _written(tmp_path) == f"wrote {tmp_path}: logs/, run.csv"


def test_a_failing_user_controller_on_the_command_line_shows_its_own_file_and_line(tmp_path: Path) -> None:
    law = f"{ROOT / 'tests' / 'user_controllers.py'}:RaisesAfter5s"
    done = subprocess.run([sys.executable, "-m", "heli_sitl.cli", "simulate", "--controller", law,
                           "--duration-s", "8", "--out", str(tmp_path), "--quiet"],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)  # fmt: skip
    assert done.returncode == 1
    err = done.stderr
    assert err.startswith(f"heli-sitl simulate: controller {law} raised:\n"), err
    assert 'user_controllers.py", line' in err, err
    assert err.endswith("RuntimeError: a bug in the user's law\n"), err
    assert "closed_loop.py" not in err and "heli_sitl/cli.py" not in err  # the bench's frames left out


def test_the_pitch_sign_table_in_the_docs_is_the_plants() -> None:
    """docs/controllers.md says which pitch moves which axis, with which sign, at hover: the
    linearised paper plant's B matrix says so too (per rad, the docs' rounding)."""
    text = (ROOT / "docs" / "controllers.md").read_text()
    b = hs.linearize("paper").b
    stated = {  # (state, input): the figure the docs give
        (W_U, THETA_M): "w +137 m/s^2", (R_Z, THETA_M): "r -169 rad/s^2", (R_Z, THETA_T): "r +148",
        (Q_Y, EPS): "q +56 rad/s^2", (U_F, EPS): "u +9.8 m/s^2", (P_X, ETA): "p +105", (V_L, ETA): "v -9.8",
    }  # fmt: skip
    for (i, j), words in stated.items():
        assert words in text, words
        figure = float(words.split()[1])
        assert b[i, j] == pytest.approx(figure, abs=0.51 if abs(figure) > 20 else 0.051), (words, b[i, j])


def test_the_lqr_examples_commands_run_as_its_docstring_writes_them() -> None:
    """Every command line the example's docstring gives parses as written (the in-process
    one flies in test_user_controller; the process and campaign ones fly elsewhere)."""
    from heli_sitl.cli import build_parser as sitl_parser

    doc = (ROOT / "docs" / "examples" / "lqr_hover.py").read_text().split('"""')[1]
    commands = [c for c in doc.split("``") if c.startswith("heli-sitl ")]
    assert len(commands) == 2, commands
    for c in commands:
        args = sitl_parser().parse_args(c.split()[1:])
        assert args.controller.endswith("lqr_hover.py:LqrHover"), c
