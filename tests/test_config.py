"""Config errors (heli_common.config): every bad file is refused with a ConfigError that names
the file, the key and what was expected."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from autopilot.scenario import Scenario
from autopilot.tlc.gains import Gains
from heli_common.config import CONFIG_DIR, ConfigError
from heli_common.vehicle.airframe import Airframe

AIRFRAME = (CONFIG_DIR / "xcell60.toml").read_text()
GAINS = (CONFIG_DIR / "gains_paper.toml").read_text()
SCENARIO = (CONFIG_DIR / "scenario_paper.toml").read_text()
MASS = "mass_kg = 8.2"
MASS_RANGE = "a finite number in (0.0, 1000.0] kg"


def edited(text: str, old: str, new: str) -> str:
    assert old in text, f"fixture drift: {old!r} not in the shipped config"
    return text.replace(old, new, 1)


def write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def airframe_error(tmp_path: Path, old: str, new: str) -> tuple[Path, str]:
    p = write(tmp_path, "airframe.toml", edited(AIRFRAME, old, new))
    with pytest.raises(ConfigError) as exc:
        Airframe.load(p)
    return p, str(exc.value)


def test_shipped_configs_load() -> None:
    af = Airframe.load()
    assert af.body.mass_kg == 8.2 and af.main_rotor.blades == 2
    assert af.limits.theta_m_rad == (-0.10, 0.30)
    g = Gains.load()
    assert g.loop4_attitude_dynamics.omega_rad_s == (12.0, 12.0, 12.0)
    sc = Scenario.load("paper")
    assert sc.run.rate_hz == 100.0 and sc.initial.pos_nwu_m == (3.0, -3.0, 3.0)


def test_round_trip_of_an_unchanged_copy(tmp_path: Path) -> None:
    assert Airframe.load(write(tmp_path, "a.toml", AIRFRAME)) == Airframe.load()


@pytest.mark.parametrize(
    ("new", "want"),
    [
        ("", "missing key (expected " + MASS_RANGE),
        ("mass_kg = nan", "expected " + MASS_RANGE + ", got nan"),
        ("mass_kg = inf", "expected " + MASS_RANGE + ", got inf"),
        ("mass_kg = -8.2", "expected " + MASS_RANGE + ", got -8.2"),
        ("mass_kg = 0.0", "expected " + MASS_RANGE + ", got 0.0"),  # open lower bound
        ("mass_kg = 1e4", "expected " + MASS_RANGE + ", got 10000.0"),
        ('mass_kg = "heavy"', "expected " + MASS_RANGE + ", got 'heavy'"),
        ("mass_kg = true", "expected " + MASS_RANGE + ", got True"),
        ("mass_kg = [8.2]", "expected " + MASS_RANGE + ", got [8.2]"),
    ],
    ids=["missing", "nan", "inf", "negative", "zero", "too-big", "string", "bool", "array"],
)
def test_bad_mass(tmp_path: Path, new: str, want: str) -> None:
    p, msg = airframe_error(tmp_path, MASS, new)
    assert msg.startswith(str(p))
    assert "body.mass_kg" in msg
    assert want in msg


def test_typo_key_suggests_the_right_one(tmp_path: Path) -> None:
    p, msg = airframe_error(tmp_path, MASS, "mass_kgg = 8.2")
    assert str(p) in msg
    assert "unknown key 'mass_kgg'" in msg
    assert "did you mean 'mass_kg'?" in msg
    assert "body" in msg and "expected one of mass_kg," in msg


def test_typo_table_suggests_the_right_one(tmp_path: Path) -> None:
    p, msg = airframe_error(tmp_path, "[tail_rotor]", "[tail_rotr]")
    assert str(p) in msg and "did you mean 'tail_rotor'?" in msg


def test_integer_field(tmp_path: Path) -> None:
    p, msg = airframe_error(tmp_path, "blades = 2 ", "blades = 2.5 ")
    assert str(p) in msg and "main_rotor.blades" in msg and "expected an integer, got 2.5" in msg


def test_integer_accepted_for_float(tmp_path: Path) -> None:
    p = write(tmp_path, "a.toml", edited(AIRFRAME, MASS, "mass_kg = 8"))
    af = Airframe.load(p)
    assert af.body.mass_kg == 8.0 and isinstance(af.body.mass_kg, float)


def test_limits_pair(tmp_path: Path) -> None:
    p, msg = airframe_error(tmp_path, "theta_m_rad = [-0.10, 0.30]", "theta_m_rad = [0.30]")
    assert str(p) in msg and "limits.theta_m_rad" in msg and "expected 2 values, got 1" in msg
    p, msg = airframe_error(tmp_path, "theta_m_rad = [-0.10, 0.30]", "theta_m_rad = [0.30, -0.10]")
    assert str(p) in msg and "theta_m_rad" in msg and "must be below upper limit" in msg
    p, msg = airframe_error(tmp_path, "eps_rad = [-0.14, 0.14]", "eps_rad = [-0.14, 0.9]")
    assert "limits.eps_rad[1]" in msg and "expected a finite number in [-0.5, 0.5] rad, got 0.9" in msg


def test_inertia_must_be_positive_definite(tmp_path: Path) -> None:
    p, msg = airframe_error(tmp_path, "ixz_kg_m2 = 0.0 ", "ixz_kg_m2 = 0.5 ")
    assert str(p) in msg and "body" in msg and "ixx*izz > ixz^2" in msg


def test_table_given_a_number(tmp_path: Path) -> None:
    start = AIRFRAME.index("[air]")
    end = AIRFRAME.index("[main_rotor]")
    text = AIRFRAME[:start] + AIRFRAME[end:]
    text = edited(text, 'name = "MIT X-Cell 60"', 'name = "MIT X-Cell 60"\nair = 1.225')
    p = write(tmp_path, "a.toml", text)
    with pytest.raises(ConfigError) as exc:
        Airframe.load(p)
    msg = str(exc.value)
    assert str(p) in msg and "air" in msg and "expected a table, got 1.225" in msg


def test_malformed_toml(tmp_path: Path) -> None:
    p, msg = airframe_error(tmp_path, MASS, "mass_kg = = 8.2")
    assert msg.startswith(str(p)) and "not valid TOML" in msg and "line 8" in msg


def test_missing_file(tmp_path: Path) -> None:
    p = tmp_path / "nope.toml"
    with pytest.raises(ConfigError) as exc:
        Airframe.load(p)
    assert str(p) in str(exc.value) and "no such config file" in str(exc.value)


def test_no_double_colon(tmp_path: Path) -> None:
    _, msg = airframe_error(tmp_path, "[air]", "[airr]")
    assert "::" not in msg


# --- gains and scenarios -------------------------------------------------------------------------


def test_gains_errors(tmp_path: Path) -> None:
    p = write(
        tmp_path,
        "g.toml",
        edited(GAINS, "omega_rad_s = [3.0, 3.0, 3.0]", "omega_rad_s = [3.0, -3.0, 3.0]"),
    )
    with pytest.raises(ConfigError) as exc:
        Gains.load(p)
    msg = str(exc.value)
    assert str(p) in msg
    assert "loop3_attitude_kinematics.omega_rad_s[1]" in msg
    assert "expected a finite number in [0.001, 200.0] rad/s, got -3.0" in msg
    p = write(tmp_path, "g2.toml", edited(GAINS, "zeta = 0.707\n", "zeta = 0.707\nzetta = 1.0\n"))
    with pytest.raises(ConfigError, match="did you mean 'zeta'"):
        Gains.load(p)


@pytest.fixture
def scenario_dir(tmp_path: Path) -> Path:
    for f in ("xcell60.toml", "gains_paper.toml"):
        shutil.copy(CONFIG_DIR / f, tmp_path / f)
    return tmp_path


def scenario_error(d: Path, old: str, new: str) -> tuple[Path, str]:
    p = write(d, "scenario_bad.toml", edited(SCENARIO, old, new))
    with pytest.raises(ConfigError) as exc:
        Scenario.load(p)
    return p, str(exc.value)


def test_scenario_copy_loads(scenario_dir: Path) -> None:
    sc = Scenario.load(write(scenario_dir, "scenario_ok.toml", SCENARIO))
    assert sc.run.name == "paper" and sc.airframe == Airframe.load()


@pytest.mark.parametrize(
    ("old", "new", "key", "want"),
    [
        (
            'feedforward = "pseudo"',
            'feedforward = "exakt"',
            "feedforward",
            "expected one of pseudo, exact, got 'exakt'",
        ),
        (
            "rate_hz = 100.0",
            "rate_hz = 10.0",
            "rate_hz",
            "expected a finite number in [50.0, 1000.0] Hz, got 10.0",
        ),
        ("plant_substeps = 1", "plant_substeps = 0", "plant_substeps", "got 0"),
        (
            'kind = "paper_spiral_circle"',
            'kind = "spiral"',
            "trajectory.kind",
            "expected one of paper_spiral_circle, straight_line, figure_eight, arc_turn, position_step, "
            "got 'spiral'",
        ),
        ("radius_m = 10.0", "radius = 10.0", "trajectory", "did you mean 'radius_m'?"),
        (
            "pos_nwu_m = [3.0, -3.0, 3.0]",
            "pos_nwu_m = [3.0, -3.0]",
            "pos_nwu_m",
            "expected 3 values, got 2",
        ),
        ("euler_rad = [0.0, 0.0, 0.1]", "euler_rad = [0.0, nan, 0.1]", "euler_rad[1]", "got nan"),
        ("[run]", "[runn]", "[run]", "missing table"),
    ],
    ids=["choice", "rate", "substeps", "kind", "typo", "length", "nan", "no-run"],
)
def test_scenario_errors(scenario_dir: Path, old: str, new: str, key: str, want: str) -> None:
    p, msg = scenario_error(scenario_dir, old, new)
    assert msg.startswith(str(p)), msg
    assert key in msg and want in msg, msg


def test_scenario_names_a_missing_airframe(scenario_dir: Path) -> None:
    _, msg = scenario_error(scenario_dir, 'airframe = "xcell60.toml"', 'airframe = "xcell61.toml"')
    assert "xcell61.toml" in msg and "no such config file" in msg


def test_unknown_scenario_name() -> None:
    with pytest.raises(ConfigError, match=r"scenario_no_such_thing\.toml: no such config file"):
        Scenario.load("no_such_thing")
