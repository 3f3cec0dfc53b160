"""MissionServer: the vehicle side of the MAVLink mission protocol, driven through real
pymavlink packing and parsing (GCS sysid 255 / compid 190, vehicle 1 / 1), with an
injected clock."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from autopilot.mission.checks import ItemLimits, check_item
from autopilot.mission.server import MissionServer
from heli_common.geo import GeoPoint, geo_to_nwu_m, nwu_to_geo
from heli_common.wire.mavlink import mission_items as ms
from heli_common.wire.mavlink.mission_items import MissionItem

HOME = GeoPoint(47.397742, 8.545594, 488.0)
GCS = (255, 190)
OTHER_GCS = (254, 190)


class Link:
    """Packs what one side sends and parses it on the other, as over a real link."""

    def __init__(self, server: MissionServer, gcs: tuple[int, int] = GCS) -> None:
        self.server = server
        self.gcs = mavlink.MAVLink(None, srcSystem=gcs[0], srcComponent=gcs[1])
        self.veh = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.veh_in = mavlink.MAVLink(None)
        self.gcs_in = mavlink.MAVLink(None)

    def send(self, msg: Any, now_s: float = 0.0) -> list[Any]:
        decoded = self.veh_in.parse_buffer(bytearray(msg.pack(self.gcs)))
        assert decoded is not None and len(decoded) == 1
        return self._back(self.server.handle(decoded[0], now_s))

    def tick(self, now_s: float) -> list[Any]:
        return self._back(self.server.tick(now_s))

    def _back(self, out: list[Any]) -> list[Any]:
        got: list[Any] = []
        for m in out:
            parsed = self.gcs_in.parse_buffer(bytearray(m.pack(self.veh)))
            assert parsed is not None
            got.extend(parsed)
        return got


def wp(seq: int, north_m: float, east_m: float, up_m: float, hold_s: float = 0.0) -> MissionItem:
    lat, lon, _ = _latlon(north_m, east_m)
    return MissionItem(seq, ms.FRAME_GLOBAL_REL_INT, ms.CMD_WAYPOINT, param1=hold_s, x=lat, y=lon, z=up_m)


def _latlon(north_m: float, east_m: float) -> tuple[int, int, float]:
    g = nwu_to_geo(HOME, (north_m, -east_m, 0.0))
    return round(g.lat_deg * 1e7), round(g.lon_deg * 1e7), g.alt_amsl_m


def mission3() -> list[MissionItem]:
    return [
        MissionItem(0, ms.FRAME_GLOBAL_REL_INT, ms.CMD_TAKEOFF, z=10.0),
        wp(1, 20.0, 5.0, 10.0),
        MissionItem(2, ms.FRAME_MISSION, ms.CMD_RTL),
    ]


def count(n: int, mission_type: int = ms.TYPE_MISSION) -> Any:
    return mavlink.MAVLink_mission_count_message(1, 1, n, mission_type)


def item_msg(item: MissionItem) -> Any:
    return item.to_message(1, 1)


def only(msgs: Sequence[Any], kind: str) -> Any:
    assert [m.get_type() for m in msgs] == [kind], msgs
    return msgs[0]


def ack_type(msgs: Sequence[Any]) -> int:
    return int(only(msgs, "MISSION_ACK").type)


def upload(link: Link, items: Sequence[MissionItem], t: float = 0.0) -> int:
    """A well-behaved GCS: answer each request; return the final ACK's result."""
    out = link.send(count(len(items)), t)
    for _ in range(len(items) + 1):
        m = out[0]
        if m.get_type() == "MISSION_ACK":
            return int(m.type)
        assert m.get_type() == "MISSION_REQUEST_INT"
        out = link.send(item_msg(items[m.seq]), t)
    raise AssertionError("upload did not finish")


def uploaded(link: Link, items: Sequence[MissionItem]) -> MissionServer:
    assert upload(link, items) == ms.ACCEPTED
    return link.server


@pytest.fixture
def link() -> Link:
    return Link(MissionServer(home=HOME))


# ------------------------------------------------------------------ upload


def test_upload_requests_each_item_in_order_then_acks(link: Link) -> None:
    items = mission3()
    req = only(link.send(count(3)), "MISSION_REQUEST_INT")
    assert (req.seq, req.target_system, req.target_component) == (0, *GCS)
    for i in range(2):
        req = only(link.send(item_msg(items[i])), "MISSION_REQUEST_INT")
        assert req.seq == i + 1
    ack = only(link.send(item_msg(items[2])), "MISSION_ACK")
    assert ack.type == ms.ACCEPTED and (ack.target_system, ack.target_component) == GCS
    assert link.server.mission == tuple(items)
    assert link.server.generation == 1 and not link.server.upload_in_progress


def test_upload_legacy_mission_item_is_converted_and_requested_legacy(link: Link) -> None:
    only(link.send(count(2)), "MISSION_REQUEST_INT")
    legacy = mavlink.MAVLink_mission_item_message(
        1, 1, 0, ms.FRAME_GLOBAL_REL, ms.CMD_WAYPOINT, 0, 1, 0, 0, 0, 0, 47.3978, 8.5457, 15.0
    )
    req = only(link.send(legacy), "MISSION_REQUEST")  # the partner speaks legacy: so do we
    assert req.seq == 1
    legacy2 = mavlink.MAVLink_mission_item_message(
        1, 1, 1, ms.FRAME_MISSION, ms.CMD_RTL, 0, 1, 0, 0, 0, 0, 0, 0, 0
    )
    assert ack_type(link.send(legacy2)) == ms.ACCEPTED
    first = link.server.mission[0]
    # float32 degrees -> degE7 (float32 is why MISSION_ITEM is deprecated: ~0.4 m steps)
    expected = (round(float(np.float32(47.3978)) * 1e7), round(float(np.float32(8.5457)) * 1e7))
    assert (first.x, first.y) == expected
    assert first.z == 15.0


def test_count_above_max_items_is_no_space_and_keeps_mission() -> None:
    link = Link(MissionServer(home=HOME, max_items=3))
    uploaded(link, mission3())
    assert ack_type(link.send(count(4))) == ms.NO_SPACE
    assert link.server.mission == tuple(mission3())


def test_item_ahead_of_sequence_rerequests_expected_once(link: Link) -> None:
    items = [wp(i, 10.0 * i, 0.0, 10.0) for i in range(4)]
    link.send(count(4))
    req = only(link.send(item_msg(items[2])), "MISSION_REQUEST_INT")  # dropped, ask again
    assert req.seq == 0
    assert link.send(item_msg(items[3])) == []  # no request storm
    assert only(link.send(item_msg(items[0])), "MISSION_REQUEST_INT").seq == 1
    for i in range(1, 3):
        only(link.send(item_msg(items[i])), "MISSION_REQUEST_INT")
    assert ack_type(link.send(item_msg(items[3]))) == ms.ACCEPTED
    assert link.server.mission == tuple(items)


def test_duplicate_item_is_dropped_silently(link: Link) -> None:
    items = mission3()
    link.send(count(3))
    link.send(item_msg(items[0]))
    assert link.send(item_msg(items[0])) == []  # a GCS answering our retry and the original
    only(link.send(item_msg(items[1])), "MISSION_REQUEST_INT")
    assert ack_type(link.send(item_msg(items[2]))) == ms.ACCEPTED


def test_gcs_streaming_all_items_without_waiting_is_accepted(link: Link) -> None:
    items = [wp(i, 5.0 * i, 1.0, 10.0) for i in range(5)]
    link.send(count(5))
    replies = [link.send(item_msg(it)) for it in items]  # not waiting for our requests
    replies.append(link.send(item_msg(items[-1])))  # and repeating the last one
    acks = [int(m.type) for r in replies for m in r if m.get_type() == "MISSION_ACK"]
    assert acks == [ms.ACCEPTED, ms.ACCEPTED]  # the final one, again for the repeat
    assert link.server.mission == tuple(items)


def test_item_with_no_upload_in_progress_is_invalid_sequence(link: Link) -> None:
    assert ack_type(link.send(item_msg(wp(0, 0, 0, 10)))) == ms.INVALID_SEQUENCE


def test_lost_final_ack_is_resent_on_repeated_last_item(link: Link) -> None:
    items = mission3()
    uploaded(link, items)
    gen = link.server.generation
    assert ack_type(link.send(item_msg(items[-1]))) == ms.ACCEPTED
    assert link.server.generation == gen  # not stored twice


def test_count_from_another_gcs_during_upload_is_denied(link: Link) -> None:
    other = Link(link.server, OTHER_GCS)
    items = mission3()
    link.send(count(3))
    assert ack_type(other.send(count(1))) == ms.DENIED
    assert ack_type(other.send(item_msg(items[0]))) == ms.DENIED
    link.send(item_msg(items[0]))
    link.send(item_msg(items[1]))
    assert ack_type(link.send(item_msg(items[2]))) == ms.ACCEPTED


def test_count_again_from_same_gcs_restarts_upload(link: Link) -> None:
    items = mission3()
    link.send(count(5))
    link.send(item_msg(wp(0, 1, 1, 5)))
    assert only(link.send(count(3)), "MISSION_REQUEST_INT").seq == 0
    assert upload(link, items) == ms.ACCEPTED
    assert link.server.mission == tuple(items)


def test_count_zero_clears_mission(link: Link) -> None:
    uploaded(link, mission3())
    assert ack_type(link.send(count(0))) == ms.ACCEPTED
    assert link.server.mission == ()


def test_gcs_cancel_abandons_upload_and_keeps_mission(link: Link) -> None:
    uploaded(link, mission3())
    link.send(count(2))
    link.send(item_msg(wp(0, 1, 1, 5)))
    assert link.send(mavlink.MAVLink_mission_ack_message(1, 1, ms.CANCELLED, 0)) == []
    assert not link.server.upload_in_progress
    assert link.server.mission == tuple(mission3())


def test_target_other_system_is_ignored(link: Link) -> None:
    assert link.send(mavlink.MAVLink_mission_count_message(2, 1, 3, 0)) == []
    assert link.send(mavlink.MAVLink_mission_count_message(1, 5, 3, 0)) == []
    assert only(link.send(mavlink.MAVLink_mission_count_message(0, 0, 3, 0)), "MISSION_REQUEST_INT")


# ------------------------------------------------------------------ bad items: one code each


def _reject(link: Link, bad: MissionItem) -> int:
    uploaded(link, mission3())
    items = [*mission3()[:1], bad]
    result = upload(link, items)
    assert link.server.mission == tuple(mission3()), "a refused upload must keep the old mission"
    assert not link.server.upload_in_progress
    return result


def test_unsupported_command(link: Link) -> None:
    bad = MissionItem(1, ms.FRAME_GLOBAL_REL_INT, mavlink.MAV_CMD_NAV_LOITER_TURNS, x=1, y=1)
    assert _reject(link, bad) == ms.UNSUPPORTED


def test_unsupported_frame_local_enu(link: Link) -> None:
    bad = MissionItem(1, mavlink.MAV_FRAME_LOCAL_ENU, ms.CMD_WAYPOINT, x=10_000, y=0, z=5.0)
    assert _reject(link, bad) == ms.UNSUPPORTED_FRAME


def test_unsupported_frame_terrain(link: Link) -> None:
    lat, lon, _ = _latlon(5, 5)
    bad = MissionItem(1, mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, ms.CMD_WAYPOINT, x=lat, y=lon)
    assert _reject(link, bad) == ms.UNSUPPORTED_FRAME


def test_mission_frame_for_positional_item_is_unsupported_frame(link: Link) -> None:
    assert _reject(link, MissionItem(1, ms.FRAME_MISSION, ms.CMD_WAYPOINT)) == ms.UNSUPPORTED_FRAME


def test_nan_altitude_is_invalid_param7(link: Link) -> None:
    assert _reject(link, wp(1, 5, 5, math.nan)) == ms.INVALID_Z


def test_altitude_out_of_range_is_invalid_param7(link: Link) -> None:
    assert _reject(link, wp(1, 5, 5, 5_000.0)) == ms.INVALID_Z


def test_latitude_out_of_range_is_invalid_x(link: Link) -> None:
    bad = MissionItem(1, ms.FRAME_GLOBAL_REL_INT, ms.CMD_WAYPOINT, x=950_000_000, y=85455940, z=5)
    assert _reject(link, bad) == ms.INVALID_X


def test_longitude_out_of_range_is_invalid_y(link: Link) -> None:
    bad = MissionItem(1, ms.FRAME_GLOBAL_REL_INT, ms.CMD_WAYPOINT, x=473977420, y=1_850_000_000)
    assert _reject(link, bad) == ms.INVALID_Y


def test_too_far_north_is_invalid_x_and_east_invalid_y(link: Link) -> None:
    assert _reject(link, wp(1, 6_000.0, 0.0, 10.0)) == ms.INVALID_X
    assert _reject(link, wp(1, 0.0, 6_000.0, 10.0)) == ms.INVALID_Y


def test_local_ned_out_of_range_is_invalid_x(link: Link) -> None:
    bad = MissionItem(1, ms.FRAME_LOCAL_NED, ms.CMD_WAYPOINT, x=10_000 * 10_000, y=0, z=-5.0)
    assert _reject(link, bad) == ms.INVALID_X


def test_waypoint_without_position_is_invalid_x(link: Link) -> None:
    bad = MissionItem(1, ms.FRAME_GLOBAL_REL_INT, ms.CMD_WAYPOINT, x=0, y=0, z=10.0)
    assert _reject(link, bad) == ms.INVALID_X


def test_nan_hold_time_is_invalid_param1(link: Link) -> None:
    assert _reject(link, wp(1, 5, 5, 10, hold_s=math.nan)) == ms.INVALID_PARAM1


def test_negative_loiter_time_is_invalid_param1(link: Link) -> None:
    lat, lon, _ = _latlon(5, 5)
    bad = MissionItem(1, ms.FRAME_GLOBAL_REL_INT, ms.CMD_LOITER_TIME, param1=-1, x=lat, y=lon, z=5)
    assert _reject(link, bad) == ms.INVALID_PARAM1


def test_change_speed_bad_type_is_invalid_param1(link: Link) -> None:
    bad = MissionItem(1, ms.FRAME_MISSION, ms.CMD_CHANGE_SPEED, param1=7, param2=3)
    assert _reject(link, bad) == ms.INVALID_PARAM1


@pytest.mark.parametrize("speed", [0.0, 100.0, math.nan, -3.0])
def test_change_speed_bad_speed_is_invalid_param2(link: Link, speed: float) -> None:
    bad = MissionItem(1, ms.FRAME_MISSION, ms.CMD_CHANGE_SPEED, param1=1, param2=speed)
    assert _reject(link, bad) == ms.INVALID_PARAM2


def test_trajectory_sample_reserved_param3_is_invalid_param3(link: Link) -> None:
    bad = MissionItem(1, ms.FRAME_LOCAL_NED, ms.CMD_TRAJ_SAMPLE, param1=1.0, param3=2.0)
    assert _reject(link, bad) == ms.INVALID_PARAM3


def test_trajectory_sample_bad_yaw_is_invalid_param4(link: Link) -> None:
    bad = MissionItem(1, ms.FRAME_LOCAL_NED, ms.CMD_TRAJ_SAMPLE, param1=1.0, param4=1000.0)
    assert _reject(link, bad) == ms.INVALID_PARAM4


def test_legacy_item_with_nan_latitude_is_invalid_x(link: Link) -> None:
    link.send(count(1))
    legacy = mavlink.MAVLink_mission_item_message(
        1, 1, 0, ms.FRAME_GLOBAL_REL, ms.CMD_WAYPOINT, 0, 1, 0, 0, 0, 0, math.nan, 8.5, 15.0
    )
    assert ack_type(link.send(legacy)) == ms.INVALID_X


def test_error_ends_the_upload(link: Link) -> None:
    link.send(count(3))
    assert ack_type(link.send(item_msg(wp(0, 5, 5, math.nan)))) == ms.INVALID_Z
    assert ack_type(link.send(item_msg(wp(1, 5, 5, 10)))) == ms.INVALID_SEQUENCE


# ------------------------------------------------------------------ timeouts and retries


def test_missing_item_is_rerequested_after_timeout(link: Link) -> None:
    link.send(count(3), 10.0)
    assert link.tick(10.2) == []
    assert only(link.tick(10.25), "MISSION_REQUEST_INT").seq == 0
    assert link.tick(10.4) == []
    assert only(link.tick(10.5), "MISSION_REQUEST_INT").seq == 0


def test_upload_abandoned_after_max_retries_keeps_old_mission(link: Link) -> None:
    uploaded(link, mission3())
    items = [wp(i, i, i, 10) for i in range(4)]
    link.send(count(4), 100.0)
    link.send(item_msg(items[0]), 100.0)
    link.send(item_msg(items[1]), 100.1)  # then the GCS goes silent half-way
    requests = 0
    t = 100.1
    out: list[Any] = []
    while t < 110.0 and link.server.upload_in_progress:
        t += 0.05
        out = link.tick(t)
        requests += sum(m.get_type() == "MISSION_REQUEST_INT" for m in out)
    assert requests == 5  # spec: up to 5 retries
    assert t == pytest.approx(100.1 + 6 * 0.25, abs=0.06)
    assert [m.get_type() for m in out] == ["MISSION_ACK", "STATUSTEXT"]
    assert out[0].type == ms.CANCELLED
    assert link.server.mission == tuple(mission3())
    # the link recovers: a new upload works
    assert upload(link, items, t + 1) == ms.ACCEPTED


def test_retry_counter_resets_on_progress() -> None:
    link = Link(MissionServer(home=HOME, max_retries=2))
    items = [wp(i, i, i, 10) for i in range(3)]
    link.send(count(3), 0.0)
    link.tick(0.25)
    link.tick(0.5)  # two retries used on item 0
    link.send(item_msg(items[0]), 0.6)
    link.tick(0.85)
    link.tick(1.1)  # two retries on item 1: still alive
    assert link.server.upload_in_progress
    link.send(item_msg(items[1]), 1.2)
    assert ack_type(link.send(item_msg(items[2]), 1.3)) == ms.ACCEPTED


# ------------------------------------------------------------------ atomicity


def test_check_mission_refusal_keeps_old_mission() -> None:
    verdict = {"code": ms.ACCEPTED}
    srv = MissionServer(home=HOME, check_mission=lambda items: verdict["code"])
    link = Link(srv)
    uploaded(link, mission3())
    verdict["code"] = ms.DENIED  # e.g. flying and the mission cannot be built
    assert upload(link, [wp(0, 1, 1, 5)]) == ms.DENIED
    assert srv.mission == tuple(mission3())
    assert ack_type(link.send(mavlink.MAVLink_mission_clear_all_message(1, 1, 0))) == ms.DENIED
    assert srv.mission == tuple(mission3())


def test_check_mission_value_error_is_invalid() -> None:
    def boom(items: tuple[MissionItem, ...]) -> int:
        raise ValueError("cannot build")

    link = Link(MissionServer(home=HOME, check_mission=boom))
    assert upload(link, mission3()) == ms.INVALID
    assert link.server.mission == ()


def test_mission_not_visible_until_final_ack(link: Link) -> None:
    uploaded(link, mission3())
    seen: list[tuple[MissionItem, ...]] = []
    link.server.on_mission_changed = seen.append
    new = [wp(0, 1, 1, 5), wp(1, 2, 2, 5)]
    link.send(count(2))
    link.send(item_msg(new[0]))
    assert link.server.mission == tuple(mission3()) and seen == []
    link.send(item_msg(new[1]))
    assert link.server.mission == tuple(new) and seen == [tuple(new)]


# ------------------------------------------------------------------ download


def request_int(seq: int, mission_type: int = 0) -> Any:
    return mavlink.MAVLink_mission_request_int_message(1, 1, seq, mission_type)


def test_download_answers_requests_in_any_order_and_duplicates(link: Link) -> None:
    items = mission3()
    uploaded(link, items)
    c = only(link.send(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), "MISSION_COUNT")
    assert (c.count, c.target_system, c.target_component) == (3, *GCS)
    # MAVProxy-style: all requests at once, some twice, out of order
    got = [only(link.send(request_int(s)), "MISSION_ITEM_INT") for s in (2, 0, 1, 0, 2)]
    assert [m.seq for m in got] == [2, 0, 1, 0, 2]
    back = {m.seq: MissionItem.from_message(m) for m in got}
    assert [back[i].command for i in range(3)] == [it.command for it in items]
    assert [m.current for m in got] == [0, 1, 0, 1, 0]  # current_seq == 0
    assert link.send(mavlink.MAVLink_mission_ack_message(1, 1, ms.ACCEPTED, 0)) == []


def test_download_legacy_request_gets_mission_item_int(link: Link) -> None:
    uploaded(link, mission3())
    m = only(link.send(mavlink.MAVLink_mission_request_message(1, 1, 1, 0)), "MISSION_ITEM_INT")
    assert m.seq == 1


def test_download_request_out_of_range_is_invalid_sequence(link: Link) -> None:
    uploaded(link, mission3())
    link.send(mavlink.MAVLink_mission_request_list_message(1, 1, 0))
    assert ack_type(link.send(request_int(3))) == ms.INVALID_SEQUENCE


def test_download_snapshot_is_consistent_while_another_gcs_uploads(link: Link) -> None:
    old = mission3()
    uploaded(link, old)
    link.send(mavlink.MAVLink_mission_request_list_message(1, 1, 0))
    other = Link(link.server, OTHER_GCS)
    assert upload(other, [wp(0, 3, 3, 3)]) == ms.ACCEPTED
    m = only(link.send(request_int(2)), "MISSION_ITEM_INT")
    assert m.command == ms.CMD_RTL  # still the mission whose count was given
    link.send(mavlink.MAVLink_mission_ack_message(1, 1, ms.ACCEPTED, 0))
    assert ack_type(link.send(request_int(2))) == ms.INVALID_SEQUENCE  # now the new one


def test_download_snapshot_expires(link: Link) -> None:
    uploaded(link, mission3())
    link.send(mavlink.MAVLink_mission_request_list_message(1, 1, 0), 0.0)
    link.send(count(0), 0.1)  # cleared by the same GCS; the snapshot still serves
    only(link.send(request_int(1), 1.0), "MISSION_ITEM_INT")
    link.tick(10.0)
    assert ack_type(link.send(request_int(1), 10.0)) == ms.INVALID_SEQUENCE


def test_download_empty_mission(link: Link) -> None:
    c = only(link.send(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), "MISSION_COUNT")
    assert c.count == 0


# ------------------------------------------------------------------ clear, set current, types


def test_clear_all(link: Link) -> None:
    uploaded(link, mission3())
    assert ack_type(link.send(mavlink.MAVLink_mission_clear_all_message(1, 1, 0))) == ms.ACCEPTED
    assert link.server.mission == ()


def test_clear_all_during_upload_is_error(link: Link) -> None:
    uploaded(link, mission3())
    link.send(count(2))
    assert ack_type(link.send(mavlink.MAVLink_mission_clear_all_message(1, 1, 0))) == ms.ERROR
    assert link.server.mission == tuple(mission3())


def test_clear_all_types_clears_mission(link: Link) -> None:
    uploaded(link, mission3())
    msg = mavlink.MAVLink_mission_clear_all_message(1, 1, ms.TYPE_ALL)
    assert ack_type(link.send(msg)) == ms.ACCEPTED
    assert link.server.mission == ()


def test_set_current_broadcasts_mission_current(link: Link) -> None:
    uploaded(link, mission3())
    cur = only(link.send(mavlink.MAVLink_mission_set_current_message(1, 1, 2)), "MISSION_CURRENT")
    assert (cur.seq, cur.total) == (2, 3)
    assert link.server.current_seq == 2


def test_set_current_out_of_range_is_statustext(link: Link) -> None:
    uploaded(link, mission3())
    only(link.send(mavlink.MAVLink_mission_set_current_message(1, 1, 3)), "STATUSTEXT")
    assert link.server.current_seq == 0


def test_set_current_refused_by_flight_logic(link: Link) -> None:
    link.server.on_set_current = lambda seq: False
    uploaded(link, mission3())
    only(link.send(mavlink.MAVLink_mission_set_current_message(1, 1, 1)), "STATUSTEXT")
    assert link.server.current_seq == 0


def test_mission_current_without_mission_reports_no_mission(link: Link) -> None:
    m = link.server.mission_current_message()
    assert m.total == ms.UINT16_MAX and m.mission_state == mavlink.MISSION_STATE_NO_MISSION


def test_progress_helpers(link: Link) -> None:
    uploaded(link, mission3())
    assert only(link._back(link.server.set_current(1)), "MISSION_CURRENT").seq == 1
    assert link.server.set_current(1) == []  # unchanged: nothing to broadcast
    assert only(link._back(link.server.item_reached(1)), "MISSION_ITEM_REACHED").seq == 1


@pytest.mark.parametrize("mtype", [ms.TYPE_FENCE, ms.TYPE_RALLY])
def test_fence_and_rally_are_accepted_empty(link: Link, mtype: int) -> None:
    c = only(link.send(mavlink.MAVLink_mission_request_list_message(1, 1, mtype)), "MISSION_COUNT")
    assert (c.count, c.mission_type) == (0, mtype)
    assert ack_type(link.send(count(0, mtype))) == ms.ACCEPTED
    assert ack_type(link.send(count(2, mtype))) == ms.UNSUPPORTED
    assert ack_type(link.send(mavlink.MAVLink_mission_clear_all_message(1, 1, mtype))) == 0


def test_mission_type_all_cannot_be_uploaded(link: Link) -> None:
    assert ack_type(link.send(count(2, ms.TYPE_ALL))) == ms.UNSUPPORTED


# ------------------------------------------------------------------ items and positions


def test_item_position_amsl_uses_home_altitude() -> None:
    lat, lon, _ = _latlon(30.0, -12.0)
    item = MissionItem(0, ms.FRAME_GLOBAL_INT, ms.CMD_WAYPOINT, x=lat, y=lon, z=HOME.alt_amsl_m + 25)
    p = ms.item_position_ned_m(item, HOME)
    assert p.north_east_m == pytest.approx((30.0, -12.0), abs=0.02)
    assert p.down_m == pytest.approx(-25.0)
    rel = MissionItem(0, ms.FRAME_GLOBAL_REL_INT, ms.CMD_WAYPOINT, x=lat, y=lon, z=25.0)
    assert ms.item_position_ned_m(rel, HOME).down_m == pytest.approx(-25.0)
    local = MissionItem(0, ms.FRAME_LOCAL_NED, ms.CMD_WAYPOINT, x=300_000, y=-120_000, z=-25.0)
    assert ms.item_position_ned_m(local, HOME) == ms.ItemPosition((30.0, -12.0), -25.0)


def test_land_here_is_accepted_and_has_no_position() -> None:
    land = MissionItem(0, ms.FRAME_GLOBAL_REL_INT, ms.CMD_LAND, z=math.nan)
    assert check_item(land, HOME) == ms.ACCEPTED
    assert ms.item_position_ned_m(land, HOME) == ms.ItemPosition(None, None)


def test_check_item_without_home_skips_range_only() -> None:
    far = MissionItem(0, ms.FRAME_GLOBAL_REL_INT, ms.CMD_WAYPOINT, x=100_000_000, y=1, z=5)
    assert check_item(far, None) == ms.ACCEPTED
    assert check_item(far, HOME) == ms.INVALID_X
    assert check_item(far, HOME, ItemLimits(max_range_m=1e7)) == ms.ACCEPTED


def test_geo_helpers_agree_with_item_encoding() -> None:
    lat, lon, _ = _latlon(100.0, 50.0)
    n, w, _ = geo_to_nwu_m(HOME, lat / 1e7, lon / 1e7, HOME.alt_amsl_m)
    assert (n, -w) == pytest.approx((100.0, 50.0), abs=0.02)


int32 = st.integers(ms.INT32_MIN, ms.INT32_MAX)
f32 = st.floats(width=32, allow_nan=True, allow_infinity=False)


@given(
    seq=st.integers(0, ms.UINT16_MAX),
    frame=st.sampled_from([0, 1, 2, 3, 5, 6]),
    command=st.sampled_from(sorted(ms.SUPPORTED_COMMANDS)),
    params=st.tuples(f32, f32, f32, f32),
    x=int32,
    y=int32,
    z=f32,
    autocontinue=st.booleans(),
)
@settings(max_examples=200, deadline=None)
def test_mission_item_int_pack_parse_round_trip(
    seq: int,
    frame: int,
    command: int,
    params: tuple[float, float, float, float],
    x: int,
    y: int,
    z: float,
    autocontinue: bool,
) -> None:
    item = MissionItem(seq, frame, command, *params, x=x, y=y, z=z, autocontinue=autocontinue)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    parsed = mavlink.MAVLink(None).parse_buffer(bytearray(item.to_message(1, 1).pack(gcs)))
    assert parsed is not None
    back = MissionItem.from_message(parsed[0])
    same_nan = [
        (math.isnan(a) and math.isnan(b)) or a == b
        for a, b in zip(
            (item.param1, item.param2, item.param3, item.param4, item.z),
            (back.param1, back.param2, back.param3, back.param4, back.z),
            strict=True,
        )
    ]
    assert all(same_nan)
    assert (back.seq, back.frame, back.command, back.x, back.y, back.autocontinue) == (
        seq,
        frame,
        command,
        x,
        y,
        autocontinue,
    )


@given(
    points=st.lists(
        st.tuples(st.floats(-2000, 2000), st.floats(-2000, 2000), st.floats(0, 500), st.floats(0, 60)),
        min_size=1,
        max_size=12,
    )
)
@settings(max_examples=40, deadline=None)
def test_upload_download_round_trip(points: list[tuple[float, float, float, float]]) -> None:
    items = [wp(i, n, e, u, hold) for i, (n, e, u, hold) in enumerate(points)]
    link = Link(MissionServer(home=HOME))
    assert upload(link, items) == ms.ACCEPTED
    c = only(link.send(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), "MISSION_COUNT")
    back = [
        MissionItem.from_message(only(link.send(request_int(s)), "MISSION_ITEM_INT")) for s in range(c.count)
    ]
    assert [replace_current(b) for b in back] == items


def replace_current(item: MissionItem) -> MissionItem:
    """Downloaded items carry current=1 on the current seq; uploads did not set it."""
    from dataclasses import replace

    return replace(item, current=False)
