"""flight.mcap (autopilot.mcap_log): what every run writes beside run.csv, read back with the
mcap reader (with and without the summary) and decoded by a CDR reader written here from the
ROS 2 rules (not the writer's code); the .tlog conversion (`heli-ground log --mcap OUT.mcap FILE.tlog`)."""

from __future__ import annotations

import math
import re
import struct
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader

import heli_sitl as hs
from autopilot.flight_log import write_flight_tlog
from autopilot.mcap_log import CHANNELS, McapMissingError, csv_values, read_run_csv, read_run_mcap, write_mcap
from ground.cli import main as ground_main
from ground.log import tlog_columns, tlog_to_mcap
from heli_common.defaults import HOME
from heli_common.frames import quaternion_to_euler
from heli_common.geo import geo_to_nwu_m
from heli_common.kinematics import wrap_pi
from heli_common.vehicle.airframe import Airframe
from heli_common.wire import servo_map

Messages = dict[str, list[tuple[int, int, dict[str, Any]]]]

# -- a CDR reader (XCDR1, little endian, as ROS 2 writes it) from the schema the file carries
_PRIM = {"bool": "?", "byte": "B", "char": "B", "int8": "b", "uint8": "B", "int16": "h",
         "uint16": "H", "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q", "float32": "f",
         "float64": "d"}  # fmt: skip


def msg_definitions(schema: str) -> tuple[str, dict[str, list[tuple[str, str]]]]:
    """The root's name ("" here) and every definition in a ros2msg schema: [(type, name)]."""
    defs: dict[str, list[tuple[str, str]]] = {}
    name = ""
    for part in re.split(r"^={80}$", schema, flags=re.M):
        lines = [ln.split("#")[0].strip() for ln in part.strip().splitlines()]
        if lines and lines[0].startswith("MSG: "):
            name, lines = lines[0][5:].strip(), lines[1:]
        defs[name] = [(ln.split()[0], ln.split()[1]) for ln in lines if ln and "=" not in ln]
    return "", defs


class Cdr:
    def __init__(self, data: bytes) -> None:
        assert data[:4] == b"\x00\x01\x00\x00", "CDR little endian encapsulation"
        self.data, self.pos = data[4:], 0

    def read(self, fmt: str) -> Any:
        size = struct.calcsize(fmt)
        self.pos += -self.pos % size
        (v,) = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return v

    def string(self) -> str:
        n = self.read("I")
        s = self.data[self.pos:self.pos + n]
        self.pos += n
        assert s.endswith(b"\x00")
        return s[:-1].decode()


def cdr_decode(schema: str, data: bytes) -> dict[str, Any]:
    root, defs = msg_definitions(schema)
    buf = Cdr(data)

    def value(typ: str) -> Any:
        if typ in _PRIM:
            return buf.read(_PRIM[typ])
        if typ == "string":
            return buf.string()
        return message(typ)

    def message(typ: str) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for t, name in defs[typ]:
            m = re.fullmatch(r"(.+?)\[(\d*)\]", t)
            if m is None:
                out[name] = value(t)
            else:
                count = int(m.group(2)) if m.group(2) else buf.read("I")
                out[name] = [value(m.group(1)) for _ in range(count)]
        return out

    msg = message(root)
    assert buf.pos == len(buf.data), "the payload is exactly the message"
    return msg


def read_mcap(path: Path, seeking: bool = True) -> tuple[Messages, dict[str, str]]:
    """Per topic: (log_time, publish_time, decoded message), in file order; the schema names.
    ``seeking``: through the summary and its indexes (log-time order); else record by record."""
    out: Messages = defaultdict(list)
    schemas: dict[str, str] = {}
    with path.open("rb") as fh:
        reader = make_reader(fh) if seeking else NonSeekingReader(fh)
        for schema, channel, msg in reader.iter_messages(log_time_order=seeking):
            assert channel.message_encoding == "cdr" and schema is not None
            assert schema.encoding == "ros2msg"
            schemas[channel.topic] = schema.name
            decoded = cdr_decode(schema.data.decode(), msg.data)
            out[channel.topic].append((msg.log_time, msg.publish_time, decoded))
    return out, schemas


def stamp_ns(m: dict[str, Any]) -> int:
    return int(m["timestamp"]["sec"]) * 10**9 + int(m["timestamp"]["nanosec"])


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
    assert schemas == {"/tf": "foxglove_msgs/msg/FrameTransforms", "/pose": "foxglove_msgs/msg/PoseInFrame",
                       "/reference/pose": "foxglove_msgs/msg/PoseInFrame",
                       "/scene": "foxglove_msgs/msg/SceneUpdate", "/fix": "foxglove_msgs/msg/LocationFix",
                       "/run": "heli_sitl/msg/RunRow"}  # fmt: skip


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
    for topic in ("/tf", "/pose", "/fix"):  # the messages' own stamps are the log times
        m = msgs[topic][7][2]
        assert stamp_ns(m["transforms"][0] if topic == "/tf" else m) == expected[7]
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
        assert row[c] == v[250] or (math.isnan(row[c]) and math.isnan(v[250])), c
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
    monkeypatch.setitem(sys.modules, "mcap", None)
    cols = {c: np.zeros(2) for c in ("t_s", "x_m", "y_m", "z_m", "phi_rad", "theta_rad", "psi_rad")}
    with pytest.raises(McapMissingError, match="pip install mcap"):
        write_mcap(cols, tmp_path / "x.mcap")
    assert flight.record is not None  # a run's record: run.csv written, the MCAP's absence said
    with pytest.warns(UserWarning, match="flight.mcap not written: .*pip install mcap"):
        flight.record.write_csv(tmp_path / "run.csv")
    assert (tmp_path / "run.csv").exists() and not (tmp_path / "flight.mcap").exists()


def test_simulate_writes_the_mcap_unless_told_not_to(tmp_path: Path) -> None:
    from heli_sitl.cli import main as sitl_main

    for flag, written in (([], True), (["--no-mcap"], False)):
        out = tmp_path / str(written)
        assert sitl_main(["simulate", "--quiet", "--duration-s", "1", "--out", str(out), *flag]) == 0
        assert (out / "run.csv").exists() and (out / "flight.mcap").exists() is written


def test_file_order_readers_and_summary(written: Path, mcap: tuple[Messages, dict[str, str]]) -> None:
    """Read record by record (no summary): the same messages as through the summary, log
    times never decreasing in file order, and the summary's statistics count them."""
    msgs, _ = mcap
    linear, _ = read_mcap(written / "flight.mcap", seeking=False)
    assert {t: [(a, b) for a, b, _ in v] for t, v in linear.items()} == {
        t: [(a, b) for a, b, _ in v] for t, v in msgs.items()}
    with (written / "flight.mcap").open("rb") as fh:
        times = [m.log_time for _, _, m in NonSeekingReader(fh).iter_messages()]
    assert times == sorted(times) and len(times) == 5 * 1001 + 1
    with (written / "flight.mcap").open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None and summary.statistics is not None
    stats = summary.statistics
    counts = {summary.channels[c].topic: k for c, k in stats.channel_message_counts.items()}
    assert counts == {t: len(v) for t, v in msgs.items()}
    assert stats.message_count == len(times) and stats.chunk_count == len(summary.chunk_indexes) >= 2
    assert (stats.message_start_time, stats.message_end_time) == (times[0], times[-1])


def test_message_indexes_point_at_their_messages(written: Path) -> None:
    """Each chunk's Message Index records (what indexed readers seek by): every entry's offset
    is a Message record of that channel and log time in the chunk's records, all of them."""
    from mcap.records import Chunk, MessageIndex
    from mcap.stream_reader import StreamReader

    chunk: Any = None
    seen = 0
    with (written / "flight.mcap").open("rb") as fh:
        for rec in StreamReader(fh, emit_chunks=True, validate_crcs=True).records:
            if isinstance(rec, Chunk):
                chunk = rec
                assert chunk.compression == "" and len(chunk.data) == chunk.uncompressed_size
            elif isinstance(rec, MessageIndex):
                for log_time, off in rec.records:
                    op, _, cid, _, lt = struct.unpack_from("<BQHIQ", chunk.data, off)
                    assert (op, cid, lt) == (0x05, rec.channel_id, log_time)
                    seen += 1
    assert seen == 5 * 1001 + 1


def test_read_run_mcap_is_run_csv(written: Path, run_csv: dict[str, np.ndarray]) -> None:
    """The /run channel read back (the view's replay) holds run.csv's numbers exactly."""
    back = read_run_mcap(written / "flight.mcap")
    assert list(back) == [*run_csv, "pos_err_m"]
    for c, v in run_csv.items():
        np.testing.assert_array_equal(back[c], v, err_msg=c)


def test_csv_values_are_the_csv_numbers() -> None:
    """run.csv's numbers (%.9g) computed without formatting, bit for bit, over magnitudes,
    signs, ties, powers of ten and the values that are not numbers."""
    rng = np.random.default_rng(7)
    x = np.concatenate([
        rng.standard_normal(20000) * 10.0 ** rng.integers(-30, 30, 20000),
        np.round(rng.standard_normal(5000), 4), 10.0 ** np.arange(-25, 25), -(10.0 ** np.arange(-5, 5)),
        [0.0, -0.0, np.nan, np.inf, -np.inf, 1e300, 5e-324, 0.5, 2.5e-9, 999999999.5, 9999999995.0, 0.125],
    ])  # fmt: skip
    expected = np.array([float(f"{v:.9g}") for v in x])
    got = csv_values(x.reshape(-1, 2) if x.size % 2 == 0 else x)
    np.testing.assert_array_equal(got.reshape(-1), expected)
    assert np.array_equal(np.signbit(got.reshape(-1)), np.signbit(expected))


def test_ticks_without_a_pose_have_no_pose_message(tmp_path: Path) -> None:
    """A tick whose pose is not finite (a lost flight's last ticks) has no /tf, /pose or /fix
    message, its /run row stays (NaN), and both readers read the file."""
    n = 6
    cols = {"t_s": np.arange(n) * 0.01, **{c: np.full(n, 0.5) for c in NEEDED_POSE},
            "x_ref_m": np.zeros(n), "y_ref_m": np.zeros(n), "z_ref_m": np.ones(n)}  # fmt: skip
    cols["x_m"] = cols["x_m"].copy()
    cols["x_m"][[2, 5]] = np.nan
    path = write_mcap(cols, tmp_path / "lost.mcap")
    for seeking in (True, False):
        msgs, _ = read_mcap(path, seeking=seeking)
        for topic in ("/tf", "/pose", "/fix"):
            assert [lt for lt, _, _ in msgs[topic]] == [0, 10**7, 3 * 10**7, 4 * 10**7], topic
        assert len(msgs["/reference/pose"]) == len(msgs["/run"]) == n
        assert math.isnan(msgs["/run"][2][2]["x_m"]) and msgs["/run"][3][2]["x_m"] == 0.5
    np.testing.assert_array_equal(read_run_mcap(path)["x_m"], cols["x_m"])


def test_read_run_mcap_reads_the_earlier_json_rows(tmp_path: Path) -> None:
    """Files of the bench's earlier writer (JSON /run rows, null for NaN) still replay."""
    from mcap.writer import Writer

    path = tmp_path / "old.mcap"
    with path.open("wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema(name="heli_sitl.RunRow", encoding="jsonschema", data=b"{}")
        cid = w.register_channel(topic="/run", message_encoding="json", schema_id=sid)
        for i, row in enumerate((b'{"t_s":0.0,"x_m":1.5}', b'{"t_s":0.01,"x_m":null}')):
            w.add_message(cid, log_time=i, publish_time=i, data=row)
        w.finish()  # type: ignore[no-untyped-call]  # (the library leaves it unannotated)
    back = read_run_mcap(path)
    np.testing.assert_array_equal(back["t_s"], [0.0, 0.01])
    np.testing.assert_array_equal(back["x_m"], [1.5, np.nan])


NEEDED_POSE = ("x_m", "y_m", "z_m", "phi_rad", "theta_rad", "psi_rad")
