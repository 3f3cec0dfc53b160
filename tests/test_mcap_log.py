"""flight.mcap (autopilot.mcap_log): what every run writes beside run.csv, read back with the
mcap reader; the .tlog conversion (`heli-ground log --mcap OUT.mcap FILE.tlog`)."""

from __future__ import annotations

import json
import math
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

import heli_sitl as hs
from autopilot.flight_log import write_flight_tlog
from autopilot.mcap_log import CHANNELS, McapMissingError, read_run_csv, write_mcap
from ground.cli import main as ground_main
from ground.log import tlog_columns, tlog_to_mcap
from heli_common.defaults import HOME
from heli_common.frames import quaternion_to_euler
from heli_common.geo import geo_to_nwu_m
from heli_common.kinematics import wrap_pi
from heli_common.vehicle.airframe import Airframe
from heli_common.wire import servo_map

Messages = dict[str, list[tuple[int, int, dict[str, Any]]]]


def read_mcap(path: Path) -> tuple[Messages, dict[str, str]]:
    """Per topic: (log_time, publish_time, decoded JSON), in file order; the schema names."""
    out: Messages = defaultdict(list)
    schemas: dict[str, str] = {}
    with path.open("rb") as fh:
        for schema, channel, msg in make_reader(fh).iter_messages(log_time_order=False):
            assert channel.message_encoding == "json" and schema is not None
            assert schema.encoding == "jsonschema"
            json.loads(schema.data)  # a valid JSON schema document
            schemas[channel.topic] = schema.name
            out[channel.topic].append((msg.log_time, msg.publish_time, json.loads(msg.data)))
    return out, schemas


@pytest.fixture(scope="module")
def flight() -> hs.FlightResult:
    f = hs.simulate(duration_s=10)
    assert f.status is hs.ExitStatus.COMPLETED
    return f


@pytest.fixture(scope="module")
def written(flight: hs.FlightResult, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The run's output directory: run.csv and the flight.mcap its writing puts beside it."""
    d = tmp_path_factory.mktemp("run")
    assert flight.record is not None
    flight.record.write_csv(d / "run.csv")
    return d


@pytest.fixture(scope="module")
def mcap(written: Path) -> tuple[Messages, dict[str, str]]:
    return read_mcap(written / "flight.mcap")


@pytest.fixture(scope="module")
def run_csv(written: Path) -> dict[str, np.ndarray]:
    return read_run_csv(written / "run.csv")


def test_every_channel_with_foxglove_schemas(mcap: tuple[Messages, dict[str, str]]) -> None:
    msgs, schemas = mcap
    assert set(msgs) == set(CHANNELS)
    assert schemas == {"/tf": "foxglove.FrameTransforms", "/pose": "foxglove.PoseInFrame",
                       "/reference/pose": "foxglove.PoseInFrame", "/scene": "foxglove.SceneUpdate",
                       "/fix": "foxglove.LocationFix", "/run": "heli_sitl.RunRow"}  # fmt: skip


def test_one_pose_per_tick_equal_to_run_csv(mcap: tuple[Messages, dict[str, str]],
                                            run_csv: dict[str, np.ndarray]) -> None:  # fmt: skip
    msgs, _ = mcap
    n = run_csv["t_s"].size
    assert n == 1001  # 10 s at 100 Hz, both ends
    for topic in ("/tf", "/pose", "/reference/pose", "/fix", "/run"):
        assert len(msgs[topic]) == n, topic
    pos = np.array([[m["pose"]["position"][a] for a in "xyz"] for _, _, m in msgs["/pose"]])
    np.testing.assert_array_equal(pos, np.column_stack([run_csv["x_m"], run_csv["y_m"], run_csv["z_m"]]))
    ref = np.array([[m["pose"]["position"][a] for a in "xyz"] for _, _, m in msgs["/reference/pose"]])
    np.testing.assert_array_equal(ref, np.column_stack([run_csv[f"{a}_ref_m"] for a in "xyz"]))
    assert all(m["frame_id"] == "world" for _, _, m in msgs["/pose"])


def test_stamps_are_simulation_time_and_monotonic(mcap: tuple[Messages, dict[str, str]],
                                                  run_csv: dict[str, np.ndarray]) -> None:  # fmt: skip
    msgs, _ = mcap
    expected = np.round(run_csv["t_s"] * 1e9).astype(np.int64)
    for topic in ("/tf", "/pose", "/fix", "/run"):
        log = np.array([lt for lt, _, _ in msgs[topic]])
        pub = np.array([pt for _, pt, _ in msgs[topic]])
        np.testing.assert_array_equal(log, pub)
        np.testing.assert_array_equal(log, expected)
        assert np.all(np.diff(log) > 0), topic
    stamp = msgs["/pose"][7][2]["timestamp"]
    assert stamp["sec"] * 10**9 + stamp["nsec"] == expected[7]
    (scene,) = msgs["/scene"]
    assert scene[0] == expected[0]


def test_unit_quaternions_match_euler_angles(mcap: tuple[Messages, dict[str, str]],
                                             run_csv: dict[str, np.ndarray]) -> None:  # fmt: skip
    msgs, _ = mcap
    for i, (_, _, m) in enumerate(msgs["/pose"]):
        q = m["pose"]["orientation"]
        w, x, y, z = q["w"], q["x"], q["y"], q["z"]
        assert abs(math.sqrt(w * w + x * x + y * y + z * z) - 1.0) < 1e-9
        phi, theta, psi = quaternion_to_euler((w, x, y, z))
        assert phi == pytest.approx(run_csv["phi_rad"][i], abs=1e-9)
        assert theta == pytest.approx(run_csv["theta_rad"][i], abs=1e-9)
        assert wrap_pi(psi - run_csv["psi_rad"][i]) == pytest.approx(0.0, abs=1e-9)
    for _, _, m in msgs["/tf"]:
        for tf in m["transforms"]:
            r = tf["rotation"]
            assert abs(math.sqrt(sum(r[k] ** 2 for k in "xyzw")) - 1.0) < 1e-9


def test_tf_tree_scene_fix_and_run_rows(mcap: tuple[Messages, dict[str, str]],
                                        run_csv: dict[str, np.ndarray]) -> None:  # fmt: skip
    msgs, _ = mcap
    tfs = msgs["/tf"][500][2]["transforms"]
    assert [(t["parent_frame_id"], t["child_frame_id"]) for t in tfs] == [
        ("world", "body"), ("body", "rotor"), ("rotor", "disc")]
    assert tfs[0]["translation"] == {a: run_csv[f"{a}_m"][500] for a in "xyz"}
    assert tfs[1]["translation"]["z"] == pytest.approx(Airframe.load().body.main_hub_above_cg_m)
    entities = {e["id"]: e for e in msgs["/scene"][0][2]["entities"]}
    assert set(entities) == {"fuselage", "rotor_disc", "reference_path"}
    assert entities["fuselage"]["frame_id"] == "body" and entities["rotor_disc"]["frame_id"] == "disc"
    disc = entities["rotor_disc"]["cylinders"][0]["size"]
    assert disc["x"] == pytest.approx(2 * Airframe.load().main_rotor.radius_m)
    assert len(entities["reference_path"]["lines"][0]["points"]) > 100
    for i in (0, 333, 1000):  # the fix back in local NWU about home
        f = msgs["/fix"][i][2]
        local = geo_to_nwu_m(HOME, f["latitude"], f["longitude"], f["altitude"])
        np.testing.assert_allclose(local, [run_csv[c][i] for c in ("x_m", "y_m", "z_m")], atol=1e-6)
    row = msgs["/run"][250][2]
    assert list(row) == [*run_csv, "pos_err_m"]
    for c, v in run_csv.items():
        assert row[c] == v[250] or (row[c] is None and math.isnan(v[250])), c
    err = math.dist([run_csv[f"{a}_ref_m"][250] for a in "xyz"], [run_csv[f"{a}_m"][250] for a in "xyz"])
    assert row["pos_err_m"] == pytest.approx(err, rel=1e-12)


def test_flight_result_to_mcap(flight: hs.FlightResult, tmp_path: Path) -> None:
    msgs, _ = read_mcap(flight.to_mcap(tmp_path / "f.mcap"))
    assert len(msgs["/pose"]) == flight.t_s.size
    z = [m["pose"]["position"]["z"] for _, _, m in msgs["/pose"]]
    np.testing.assert_array_equal(z, flight.state[:, 2])


def test_flapping_tilts_the_disc(tmp_path: Path) -> None:
    n = 3
    zero = ("x_m", "y_m", "z_m", "phi_rad", "theta_rad", "psi_rad")
    cols = {"t_s": np.arange(n) * 0.01, **{c: np.zeros(n) for c in zero},
            "a1_rad": np.array([0.0, 0.05, 0.0]), "b1_rad": np.array([0.0, 0.0, -0.03])}
    msgs, _ = read_mcap(write_mcap(cols, tmp_path / "flap.mcap"))
    discs = [m["transforms"][2]["rotation"] for _, _, m in msgs["/tf"]]
    euler = [quaternion_to_euler((d["w"], d["x"], d["y"], d["z"])) for d in discs]
    np.testing.assert_allclose(euler, [(0, 0, 0), (0, 0.05, 0), (-0.03, 0, 0)], atol=1e-12)
    assert "/reference/pose" not in msgs  # no reference columns: no reference pose


def test_tlog_converted_has_its_poses(flight: hs.FlightResult, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    rec = flight.record
    assert rec is not None
    tlog = tmp_path / "flight.tlog"
    limits = servo_map.limits_array(Airframe.load().limits.as_tuple())
    write_flight_tlog(tlog, rec, limits, 1_700_000_000_000_000)
    out, n = tlog_to_mcap(tlog, tmp_path / "a.mcap")
    assert n == rec.t_s.size
    msgs, _ = read_mcap(out)
    cols = tlog_columns(tlog)
    pos = np.array([[m["pose"]["position"][a] for a in "xyz"] for _, _, m in msgs["/pose"]])
    np.testing.assert_array_equal(pos, np.column_stack([cols["x_m"], cols["y_m"], cols["z_m"]]))
    np.testing.assert_allclose(pos, rec.x[:, 0:3], atol=1e-5)  # LOCAL_POSITION_NED is float32
    assert len(msgs["/reference/pose"]) > 0.9 * n
    # the command line: heli-ground log --mcap OUT.mcap FILE.tlog
    assert ground_main(["log", "--mcap", str(tmp_path / "cli.mcap"), str(tlog)]) == 0
    assert "cli.mcap" in capsys.readouterr().out
    assert len(read_mcap(tmp_path / "cli.mcap")[0]["/pose"]) == n


def test_missing_mcap_package_is_named(flight: hs.FlightResult, tmp_path: Path,
                                       monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    monkeypatch.setitem(sys.modules, "mcap.writer", None)
    cols = {c: np.zeros(2) for c in ("t_s", "x_m", "y_m", "z_m", "phi_rad", "theta_rad", "psi_rad")}
    with pytest.raises(McapMissingError, match="pip install mcap"):
        write_mcap(cols, tmp_path / "x.mcap")
    assert flight.record is not None  # a run's record: run.csv written, the MCAP's absence said
    with pytest.warns(UserWarning, match="flight.mcap not written: .*pip install mcap"):
        flight.record.write_csv(tmp_path / "run.csv")
    assert (tmp_path / "run.csv").exists() and not (tmp_path / "flight.mcap").exists()
