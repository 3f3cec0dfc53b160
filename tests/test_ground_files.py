"""ground.files: QGC WPL 110 and .plan round trips (and what MAVProxy's reader makes of our
files), trajectory TOML / CSV -> the timed-trajectory items, and errors that name file and line."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from autopilot import trajectory_codec as codec
from autopilot.trajectory.analytic import PaperSpiralCircle
from ground import files
from ground.files import FileFormatError, TrajectorySamples
from heli_common.geo import GeoPoint, nwu_to_geo
from heli_common.wire.mavlink import mission_items as ms
from heli_common.wire.mavlink.mission_items import MissionItem

HOME = GeoPoint(47.397742, 8.545594, 488.0)
CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def gwp(seq: int, north_m: float, west_m: float, up_m: float, cmd: int = ms.CMD_WAYPOINT,
        frame: int = ms.FRAME_GLOBAL_REL_INT, **kw: Any) -> MissionItem:  # fmt: skip
    g = nwu_to_geo(HOME, (north_m, west_m, 0.0))
    return MissionItem(seq, frame, cmd, x=round(g.lat_deg * 1e7), y=round(g.lon_deg * 1e7), z=up_m, **kw)


def sample_mission() -> list[MissionItem]:
    """Every frame family and the awkward values: NaN yaw, 0/0 "land here", local metres."""
    return [
        gwp(0, 0.0, 0.0, 2.5, ms.CMD_TAKEOFF),
        gwp(1, 3.0, 0.0, 2.5, param4=math.nan),
        gwp(2, 3.0, 3.0, 3.0, frame=ms.FRAME_GLOBAL_REL, param1=1.5),
        gwp(3, -2.0, 1.0, 490.5, frame=ms.FRAME_GLOBAL_INT),
        MissionItem(4, ms.FRAME_LOCAL_NED, ms.CMD_WAYPOINT, x=12345, y=-67890, z=-2.75),
        MissionItem(5, ms.FRAME_MISSION, ms.CMD_CHANGE_SPEED, param1=1.0, param2=1.5, param3=-1.0),
        MissionItem(6, ms.FRAME_GLOBAL_REL_INT, ms.CMD_LAND, x=0, y=0, z=0.0),
    ]


def write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


# ----------------------------------------------------------------------------- .waypoints


def test_waypoints_round_trip_keeps_home_out_of_the_items(tmp_path: Path) -> None:
    items = sample_mission()
    p = tmp_path / "m.waypoints"
    files.write_waypoints(p, items, HOME)
    lines = p.read_text().splitlines()
    assert lines[0] == "QGC WPL 110"
    assert lines[1].split("\t")[:4] == ["0", "1", "0", "16"]  # line 0: home, global AMSL
    assert len(lines) == 1 + 1 + len(items)
    got = files.read_waypoints(p)
    assert got.home == HOME
    assert list(got.items) == items  # seq renumbered from 0: home is not an item
    assert got.kind == "waypoints" and not got.is_trajectory


def test_waypoints_as_mavproxy_reads_them(tmp_path: Path) -> None:
    """MAVProxy's `wp load` uses pymavlink's MAVWPLoader: our file must mean the same to it
    (it keeps line 0 as item 0 and floats for x/y; it truncates x * 1e7 when it uploads)."""
    from pymavlink import mavutil, mavwp

    # mavutil picks MAVLink 1 or 2 from $MAVLINK20 when first imported and mavwp asks again
    # when it builds items; heli_common.wire.mavlink.udp may set it in between: make them agree.
    mavutil.set_dialect("common")
    items = sample_mission()
    p = tmp_path / "m.waypoints"
    files.write_waypoints(p, items, HOME)
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(p)) == len(items) + 1
    home = loader.wp(0)
    assert (home.x, home.y, home.z) == pytest.approx((HOME.lat_deg, HOME.lon_deg, HOME.alt_amsl_m))
    for it in items:
        w = loader.wp(it.seq + 1)
        assert (w.frame, w.command, w.autocontinue) == (it.frame, it.command, int(it.autocontinue))
        x, y = files._xy_to_file(it)
        assert w.x == pytest.approx(x, abs=1e-9) and w.y == pytest.approx(y, abs=1e-9)
        for a, b in ((w.param1, it.param1), (w.param4, it.param4), (w.z, it.z)):
            assert (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b)


def test_waypoints_written_by_other_tools(tmp_path: Path) -> None:
    """Space-separated, integer-looking floats, a relative-altitude home line (no AMSL home)."""
    text = ("QGC WPL 110\n"
            "0 1 3 16 0 0 0 0 47.3977420 8.5455940 0.0 1\n"
            "1 0 3 22 0.0 0.0 0.0 0.0 47.3977420 8.5455940 10.000000 1\n"
            "2 0 3 16 0.0 2.0 0.0 nan 47.3978 8.5456 10 1\n")  # fmt: skip
    got = files.read_waypoints(write(tmp_path, "w.txt", text))
    assert got.home is None
    assert [it.command for it in got.items] == [22, 16]
    assert got.items[1].x == 473978000 and got.items[1].y == 85456000
    assert math.isnan(got.items[1].param4) and got.items[1].param2 == 2.0


@pytest.mark.parametrize(
    ("text", "line", "fragment"),
    [
        ("QGC WPL 100\n0 1 0 16 0 0 0 0 47 8 488 1\n", 1, "unsupported version"),
        ("QGC WPX\n", 1, "header"),
        ("QGC WPL 110\n0 1 0 16 0 0 0 0 47 8 488 1\n1 0 3 16 0 0 0 0 47 8 1\n", 3, "12 columns"),
        ("QGC WPL 110\n0 1 0 16 0 0 0 0 47 8 488 1\n\n1 0 3 16 0 0 0 0 4x7 8 1 1\n", 4, "column 9"),
        ("QGC WPL 110\n0 1 0 16 0 0 0 0 47 8 488 1\n2 0 3 16 0 0 0 0 47 8 1 1\n", 3, "index 2, expected 1"),
        ("QGC WPL 110\n0 1 0 16 0 0 0 0 47 8 488 1\n1 0 3 16 0 0 0 0 97 8 1 1\n", 3, "latitude 97"),
        ("QGC WPL 110\n0 1 0 16 0 0 0 0 47 8 488 1\n1 0 3 16.5 0 0 0 0 47 8 1 1\n", 3, "integer"),
        ("QGC WPL 110\n0 1 0 16 0 0 0 0 47 8 488 1\n1 0 1 16 0 0 0 0 inf 0 1 1\n", 3, "not finite"),
    ],
)
def test_waypoints_errors_name_file_and_line(tmp_path: Path, text: str, line: int, fragment: str) -> None:
    p = write(tmp_path, "bad.waypoints", text)
    with pytest.raises(FileFormatError) as err:
        files.read_waypoints(p)
    assert err.value.line == line
    assert str(err.value).startswith(f"{p}:{line}: ")
    assert fragment in str(err.value)


# ----------------------------------------------------------------------------- .plan


def test_plan_round_trip_and_json_layout(tmp_path: Path) -> None:
    items = sample_mission()
    p = tmp_path / "m.plan"
    files.write_plan(p, items, HOME)
    doc = json.loads(p.read_text())
    assert doc["fileType"] == "Plan" and doc["mission"]["version"] == 2
    assert doc["mission"]["plannedHomePosition"] == [HOME.lat_deg, HOME.lon_deg, HOME.alt_amsl_m]
    assert doc["mission"]["items"][1]["params"][3] is None  # NaN yaw is null, as QGC writes it
    assert doc["mission"]["items"][0]["doJumpId"] == 1
    got = files.read_plan(p)
    assert got.home == HOME
    assert list(got.items) == items


def test_plan_as_qgroundcontrol_writes_it(tmp_path: Path) -> None:
    doc = {
        "fileType": "Plan", "groundStation": "QGroundControl", "version": 1,
        "geoFence": {"circles": [], "polygons": [], "version": 2},
        "rallyPoints": {"points": [], "version": 2},
        "mission": {
            "cruiseSpeed": 15, "firmwareType": 12, "globalPlanAltitudeMode": 1, "hoverSpeed": 5,
            "vehicleType": 2, "version": 2, "plannedHomePosition": [47.397742, 8.545594, 488],
            "items": [
                {"AMSLAltAboveTerrain": None, "Altitude": 5, "AltitudeMode": 1, "autoContinue": True,
                 "command": 22, "doJumpId": 1, "frame": 3, "type": "SimpleItem",
                 "params": [0, 0, 0, None, 47.397742, 8.545594, 5]},
                {"autoContinue": True, "command": 16, "doJumpId": 2, "frame": 3, "type": "SimpleItem",
                 "params": [0, 0, 0, None, 47.3978, 8.5456, 5]},
            ],
        },
    }  # fmt: skip
    got = files.read_plan(write(tmp_path, "q.plan", json.dumps(doc)))
    assert got.home == HOME
    assert [(it.command, it.frame, it.x, it.y, it.z) for it in got.items] == [
        (22, 3, 473977420, 85455940, 5.0), (16, 3, 473978000, 85456000, 5.0)]
    assert math.isnan(got.items[0].param4)


def test_plan_errors(tmp_path: Path) -> None:
    bad_json = write(tmp_path, "a.plan", '{\n  "fileType": "Plan",\n  "mission": {,}\n}\n')
    with pytest.raises(FileFormatError) as err:
        files.read_plan(bad_json)
    assert err.value.line == 3 and "not valid JSON" in str(err.value)
    survey = {"fileType": "Plan", "mission": {"version": 2, "items": [
        {"type": "ComplexItem", "complexItemType": "survey"}]}}  # fmt: skip
    with pytest.raises(FileFormatError, match=r"mission\.items\[0\]: complex item 'survey'"):
        files.read_plan(write(tmp_path, "b.plan", json.dumps(survey)))
    short = {"fileType": "Plan", "mission": {"items": [
        {"type": "SimpleItem", "command": 16, "frame": 3, "params": [0, 0, 0]}]}}  # fmt: skip
    with pytest.raises(FileFormatError, match=r"items\[0\]\.params: expected 7 values"):
        files.read_plan(write(tmp_path, "c.plan", json.dumps(short)))
    with pytest.raises(FileFormatError, match='"fileType" must be "Plan"'):
        files.read_plan(write(tmp_path, "d.plan", "{}"))


# ----------------------------------------------------------------------------- properties

finite = st.floats(-1e4, 1e4, allow_nan=False, width=32)
param = st.one_of(finite, st.just(math.nan))
FRAMES = st.sampled_from([ms.FRAME_GLOBAL_REL_INT, ms.FRAME_GLOBAL, ms.FRAME_LOCAL_NED, ms.FRAME_MISSION])


@st.composite
def items_strategy(draw: st.DrawFn) -> list[MissionItem]:
    n = draw(st.integers(0, 8))
    out = []
    for seq in range(n):
        frame = draw(FRAMES)
        if frame in ms.GLOBAL_FRAMES:
            x = draw(st.integers(-900_000_000, 900_000_000))  # degE7
            y = draw(st.integers(-1_800_000_000, 1_800_000_000))
        elif frame == ms.FRAME_LOCAL_NED:
            x, y = draw(st.integers(-(2**31), 2**31 - 1)), draw(st.integers(-(2**31), 2**31 - 1))
        else:
            x = y = 0  # x/y of MAV_FRAME_MISSION items are not carried by the files' float columns
        p1, p2, p3, p4 = (draw(param) for _ in range(4))
        out.append(MissionItem(seq, frame, draw(st.integers(0, 65535)), p1, p2, p3, p4,
                               x=x, y=y, z=draw(param), autocontinue=draw(st.booleans())))  # fmt: skip
    return out


@settings(max_examples=60)
@given(items=items_strategy())
def test_files_round_trip_any_items(
    tmp_path_factory: pytest.TempPathFactory, items: list[MissionItem]
) -> None:
    d = tmp_path_factory.mktemp("rt")
    files.write_waypoints(d / "p.waypoints", items, HOME)
    files.write_plan(d / "p.plan", items, HOME)
    assert list(files.read_waypoints(d / "p.waypoints").items) == items
    assert list(files.read_plan(d / "p.plan").items) == items


# ----------------------------------------------------------------------------- trajectories


def test_paper_scenario_toml_becomes_the_spiral() -> None:
    """The scenario file itself: its [trajectory] table, sampled at 0.5 s with the 40 s corner."""
    mf = files.load_mission(CONFIGS / "scenario_paper.toml")
    assert mf.kind == "trajectory" and mf.is_trajectory and mf.duration_s == 120.0
    assert len(mf.items) == 1 + 241
    assert mf.items[81].param1 == 40.0 and mf.items[81].param2 == ms.BREAK_MASK_ALL & 0b100
    decoded = codec.decode(mf.items)
    assert decoded is not None
    t = np.arange(0.0, 120.0, 0.01)
    err = np.abs(decoded.sample(t)[:, 0:3] - PaperSpiralCircle().sample(t)[:, 0:3]).max()
    assert err < 1e-4  # codec docstring: 5.4e-5 m at 0.5 s


def test_trajectory_toml_encoding_table_and_errors(tmp_path: Path) -> None:
    ok = write(tmp_path, "line.toml", '[trajectory]\nkind = "straight_line"\nstart_nwu_m = [0.0, 0.0, 2.0]\n'
               'vel_nwu_m_s = [1.0, 0.0, 0.0]\nduration_s = 10.0\n\n[encoding]\ndt_s = 2.0\n')  # fmt: skip
    mf = files.load_mission(ok)
    assert len(mf.items) == 1 + 6 and mf.duration_s == 10.0
    assert len(files.load_mission(ok, dt_s=1.0).items) == 1 + 11
    cases = [
        ('[trajectory]\nkind = "straight_line"\nduration_s = -1.0\n', 3, "duration_s"),
        ('[trajectory]\nkind = "spiral"\n', 2, "kind"),
        ('[trajectory]\nkind = "straight_line"\n\n[encoding]\nstep = 1\n', 5, "encoding.step: unknown key"),
        ('[trajectory]\nkind = "straight_line"\n[encoding]\ndt_s = 0\n', 4, "dt_s"),
        ('[trajectory]\nkind = "straight_line"\nduration_s = = 3\n', 3, "not valid TOML"),
    ]
    for text, line, fragment in cases:
        p = write(tmp_path, "bad.toml", text)
        with pytest.raises(FileFormatError) as err:
            files.load_mission(p)
        assert (err.value.line, fragment in str(err.value)) == (line, True), str(err.value)
        assert str(err.value).startswith(f"{p}:{line}: ")
    with pytest.raises(FileFormatError, match=r"missing table \[trajectory\]"):
        files.load_mission(write(tmp_path, "none.toml", "[run]\nname = 'x'\n"))


def test_trajectory_csv_round_trip(tmp_path: Path) -> None:
    t = np.linspace(0.0, 8.0, 17)
    pos = np.column_stack([np.sin(t), 2.0 * np.cos(t), 1.0 + 0.1 * t])
    yaw = 0.3 * t - 1.0
    p = tmp_path / "traj.csv"
    files.write_trajectory_csv(p, TrajectorySamples(t, pos, yaw))
    back = files.read_trajectory_csv(p)
    assert np.array_equal(back.t_s, t) and np.array_equal(back.pos_nwu_m, pos)
    assert back.yaw_nwu_rad is not None and np.array_equal(back.yaw_nwu_rad, yaw)
    mf = files.load_mission(p)
    assert mf.is_trajectory and mf.duration_s == 8.0 and len(mf.items) == 18
    decoded = codec.decode(mf.items)
    assert decoded is not None
    assert np.abs(decoded.sample(t)[:, 0:3] - pos).max() < 2e-4  # 0.1 mm x/y quantum on the wire


@pytest.mark.parametrize(
    ("text", "line", "fragment"),
    [
        ("t,x,y\n0,0,0\n", 1, "expected t,x,y,z"),
        ("# a comment\nt,x,y,z\n0,0,0,0\n1,0,0,abc\n", 4, "z: not a number"),
        ("t,x,y,z\n0,0,0,0\n1,1,0,0\n1,2,0,0\n", 4, "does not increase"),
        ("t,x,y,z\n0,0,0,0\n1,nan,0,0\n", 3, "not finite"),
        ("t,x,y,z,yaw\n0,0,0,0,0\n1,1,1\n", 3, "expected 5 values"),
        ("t,x,y,z\n-1,0,0,0\n1,1,0,0\n", 2, ">= 0"),
    ],
)
def test_trajectory_csv_errors(tmp_path: Path, text: str, line: int, fragment: str) -> None:
    p = write(tmp_path, "bad.csv", text)
    with pytest.raises(FileFormatError) as err:
        files.read_trajectory_csv(p)
    assert err.value.line == line and fragment in str(err.value), str(err.value)


def test_trajectory_csv_needs_two_samples_and_known_extension(tmp_path: Path) -> None:
    with pytest.raises(FileFormatError, match="at least 2 samples"):
        files.load_mission(write(tmp_path, "one.csv", "t,x,y,z\n0,0,0,0\n"))
    with pytest.raises(FileFormatError, match="unknown file type"):
        files.load_mission(write(tmp_path, "m.kml", ""))
    with pytest.raises(FileFormatError, match="cannot read"):
        files.load_mission(tmp_path / "missing.waypoints")


def test_the_shipped_example_missions_load_and_agree() -> None:
    """The README flies configs/missions/square.waypoints; the .plan is the same mission."""
    from heli_common.config import CONFIG_DIR

    wp = files.load_mission(CONFIG_DIR / "missions" / "square.waypoints")
    plan = files.load_mission(CONFIG_DIR / "missions" / "square.plan")
    assert [(i.command, i.x, i.y, i.z) for i in wp.items] == [(i.command, i.x, i.y, i.z) for i in plan.items]
    assert [i.command for i in wp.items] == [ms.CMD_TAKEOFF, *[ms.CMD_WAYPOINT] * 3, ms.CMD_LAND]
