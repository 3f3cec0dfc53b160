"""MAVSDK (a real third-party API client) against the vehicle of ``heli-sitl up``.

mavsdk 4.x is the native binding: it loads libcmavsdk.so shipped in the wheel (no
mavsdk_server process, no gRPC), and its API is ``Mavsdk(Configuration)`` +
``add_any_connection(url)`` + ``first_autopilot()``, with plugins constructed on the
system (``TelemetryAsync(system)``, ``MissionRawAsync(system)``, ``ActionAsync(system)``)
instead of the 3.x ``System().connect(system_address=...)``. MAVSDK connects as PX4 SITL
clients do: it listens where the vehicle's API link sends (``udpin://127.0.0.1:PORT``).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import signal
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission_raw import MissionItem as RawItem
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync
from vehicle import free_ports, spawn_up

from heli_common.frames import flip
from heli_common.geo import GeoPoint, nwu_to_geo
from heli_common.wire.mavlink import mission_items as ms

HOME = GeoPoint(47.397742, 8.545594, 488.0)
START_S = 60.0
OFFBOARD_LIMIT_S = 30.0  # wall-clock bound on settling at the offboard setpoint (about 5 s alone)
SETTLED_M = 0.3  # within this of the setpoint for 2 s: settled


@contextmanager
def running_vehicle() -> Iterator[int]:
    """``heli-sitl up`` on random ports; yields the API port (where MAVSDK listens)."""
    ports = free_ports()
    api = ports.api
    proc = spawn_up(ports)
    try:
        yield api
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def raw_item(seq: int, north_m: float, west_m: float, up_m: float, command: int) -> Any:
    """A MISSION_ITEM_INT for mission_raw (GLOBAL_RELATIVE_ALT_INT, degE7)."""
    g = nwu_to_geo(HOME, (north_m, west_m, 0.0))
    return RawItem(seq, ms.FRAME_GLOBAL_REL_INT, command, 1 if seq == 0 else 0, 1, 0.0, 0.0, 0.0, math.nan,
                   round(g.lat_deg * 1e7), round(g.lon_deg * 1e7), up_m, 0)  # fmt: skip


WAYPOINTS_NWU = [(0.0, 0.0, 2.5), (3.0, 0.0, 2.5), (3.0, -2.0, 3.0)]  # takeoff, then two waypoints


@dataclass
class Seen:
    positions_ned: list[tuple[float, float, float]] = field(default_factory=list)
    progress: list[tuple[int, int]] = field(default_factory=list)
    landed_states: list[Any] = field(default_factory=list)
    first_position: Any = None
    first_attitude: Any = None
    first_velocity: Any = None
    home_ok_after_s: float | None = None
    health: Any = None
    downloaded: list[Any] = field(default_factory=list)
    flight_s: float = 0.0


async def first(gen: Any, timeout_s: float) -> Any:
    async def get() -> Any:
        async for v in gen:
            return v
        return None

    return await asyncio.wait_for(get(), timeout_s)


async def fly_with_mavsdk(api_port: int, seen: Seen) -> None:
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
        await sdk.add_any_connection(f"udpin://127.0.0.1:{api_port}")
        system = await sdk.first_autopilot(timeout_s=START_S)
        assert system is not None, "MAVSDK found no autopilot"
        tel, mission, action = TelemetryAsync(system), MissionRawAsync(system), ActionAsync(system)

        seen.first_position = await first(tel.subscribe_position(), 10.0)
        seen.first_attitude = await first(tel.subscribe_attitude_euler(), 10.0)
        seen.first_velocity = await first(tel.subscribe_velocity_ned(), 10.0)
        t0 = time.monotonic()

        async def home_ok() -> Any:
            async for h in tel.subscribe_health():
                if h.is_home_position_ok:
                    return h
            return None

        await asyncio.wait_for(home_ok(), 10.0)
        seen.home_ok_after_s = time.monotonic() - t0
        await asyncio.sleep(1.5)  # one more SYS_STATUS (1 Hz) and HEARTBEAT
        seen.health = await first(tel.subscribe_health(), 5.0)

        n = len(WAYPOINTS_NWU) + 1
        items = [raw_item(i, *wp, ms.CMD_TAKEOFF if i == 0 else ms.CMD_WAYPOINT)
                 for i, wp in enumerate(WAYPOINTS_NWU)]  # fmt: skip
        items.append(RawItem(n - 1, ms.FRAME_GLOBAL_REL_INT, ms.CMD_LAND, 0, 1, 0.0, 0.0, 0.0, math.nan,
                             0, 0, 0.0, 0))  # fmt: skip
        await mission.upload_mission(items)
        seen.downloaded = list(await mission.download_mission())

        async def positions() -> None:
            async for pv in tel.subscribe_position_velocity_ned():
                seen.positions_ned.append((pv.position.north_m, pv.position.east_m, pv.position.down_m))

        async def landed() -> None:
            async for s in tel.subscribe_landed_state():
                seen.landed_states.append(s)

        async def finished() -> None:
            async for p in mission.subscribe_mission_progress():
                seen.progress.append((p.current, p.total))
                if p.total > 0 and p.current == p.total:
                    return

        async def back_on_ground() -> None:
            was_airborne = False
            while True:
                await asyncio.sleep(0.2)
                if seen.landed_states and seen.landed_states[-1] == LandedState.IN_AIR:
                    was_airborne = True
                if was_airborne and seen.landed_states[-1] == LandedState.ON_GROUND:
                    return

        tasks = [asyncio.create_task(c) for c in (positions(), landed())]
        try:
            done_task = asyncio.create_task(finished())
            await action.arm()
            await mission.start_mission()
            t1 = time.monotonic()
            await asyncio.wait_for(back_on_ground(), 90.0)
            seen.flight_s = time.monotonic() - t1
            with contextlib.suppress(TimeoutError):  # the progress report may trail touchdown
                await asyncio.wait_for(done_task, 3.0)
        finally:
            for t in [*tasks, done_task]:
                t.cancel()
            await asyncio.gather(*tasks, done_task, return_exceptions=True)


@pytest.fixture(scope="module")
def seen() -> Seen:
    s = Seen()
    with running_vehicle() as api:
        asyncio.run(asyncio.wait_for(fly_with_mavsdk(api, s), 180.0))
    return s


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_mavsdk_telemetry_and_health(seen: Seen) -> None:
    pos, att, vel = seen.first_position, seen.first_attitude, seen.first_velocity
    assert abs(pos.latitude_deg - HOME.lat_deg) < 1e-5 and abs(pos.longitude_deg - HOME.lon_deg) < 1e-5
    assert abs(pos.absolute_altitude_m - HOME.alt_amsl_m) < 0.5 and abs(pos.relative_altitude_m) < 0.5
    assert all(math.isfinite(v) for v in (att.roll_deg, att.pitch_deg, att.yaw_deg))
    assert all(math.isfinite(v) for v in (vel.north_m_s, vel.east_m_s, vel.down_m_s))
    print(f"MAVSDK: home position ok after {seen.home_ok_after_s:.2f} s; health {vars(seen.health)}")
    h = seen.health
    assert h.is_home_position_ok and h.is_global_position_ok and h.is_local_position_ok
    assert h.is_gyrometer_calibration_ok and h.is_accelerometer_calibration_ok


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_mavsdk_mission_raw_is_flown_through_every_waypoint(seen: Seen) -> None:
    assert [(it.command, it.x, it.y) for it in seen.downloaded] == [
        (ms.CMD_TAKEOFF, *_deg_e7(WAYPOINTS_NWU[0])), (ms.CMD_WAYPOINT, *_deg_e7(WAYPOINTS_NWU[1])),
        (ms.CMD_WAYPOINT, *_deg_e7(WAYPOINTS_NWU[2])), (ms.CMD_LAND, 0, 0)]  # fmt: skip
    pos_nwu = np.array([flip(p) for p in seen.positions_ned])
    closest = [float(np.linalg.norm(pos_nwu - np.array(wp), axis=1).min()) for wp in WAYPOINTS_NWU]
    print(f"MAVSDK flight {seen.flight_s:.1f} s; closest approach per waypoint "
          f"{[round(c, 3) for c in closest]} m; progress reports {seen.progress}")
    assert all(c < 1.0 for c in closest), closest
    assert pos_nwu[-1][2] < 0.1  # back on the ground


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_mavsdk_sees_the_mission_finished(seen: Seen) -> None:
    """MAVSDK calls a mission finished when MISSION_ITEM_REACHED arrives for the last item
    (MissionRawImpl: current = reached seq + 1 == total)."""
    assert seen.progress and seen.progress[-1] == (4, 4), f"mission progress reports: {seen.progress}"


def _deg_e7(wp: tuple[float, float, float]) -> tuple[int, int]:
    g = nwu_to_geo(HOME, (wp[0], wp[1], 0.0))
    return round(g.lat_deg * 1e7), round(g.lon_deg * 1e7)


@dataclass
class Actions:
    took_off_to_m: float = 0.0
    modes: list[Any] = field(default_factory=list)
    offboard_reached_m: float = math.inf
    offboard_settled: bool = False
    home_dist_after_rtl_m: float = math.inf
    landed_after: bool = False


async def fly_actions(api_port: int, out: Actions) -> None:
    """What a MAVSDK script does: take off, hold, offboard, return to launch, land."""
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw

    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
        await sdk.add_any_connection(f"udpin://127.0.0.1:{api_port}")
        system = await sdk.first_autopilot(timeout_s=START_S)
        assert system is not None
        tel, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        await first(tel.subscribe_position(), 10.0)

        async def until(pred: Any, timeout_s: float) -> Any:
            async def wait() -> Any:
                async for pv in tel.subscribe_position_velocity_ned():
                    if pred(pv):
                        return pv
                return None

            return await asyncio.wait_for(wait(), timeout_s)

        async def mode() -> Any:
            return FlightMode(int(await first(tel.subscribe_flight_mode(), 5.0)))

        await action.set_takeoff_altitude(3.0)
        await action.arm()
        await action.takeoff()
        await asyncio.sleep(0.5)
        out.modes.append(await mode())  # climbing: TAKEOFF, as MAVSDK names it
        pv = await until(lambda pv: -pv.position.down_m > 2.85, 30.0)
        out.took_off_to_m = -pv.position.down_m
        await asyncio.sleep(3.0)
        out.took_off_to_m = -(await first(tel.subscribe_position_velocity_ned(), 5.0)).position.down_m
        await action.hold()
        await asyncio.sleep(1.0)
        out.modes.append(await mode())
        # offboard: a setpoint before start, as MAVSDK requires, then 2 m north
        target = PositionNedYaw(2.0, 0.0, -3.0, 0.0)
        await offboard.set_position_ned(target)
        await offboard.start()
        # setpoints at 10 Hz until the vehicle has stayed within SETTLED_M of the target for
        # 2 s (a 2 m step: the TLC overshoots it, then settles). Judged on what the vehicle
        # reports, not on this client's wall clock: a loaded machine may pause the vehicle's
        # real-time clock after a stall, and 8 s of the client's time were then too few
        loop = asyncio.get_running_loop()
        give_up, inside_since = loop.time() + OFFBOARD_LIMIT_S, None
        while loop.time() < give_up:
            await offboard.set_position_ned(target)
            await asyncio.sleep(0.1)
            pv = await first(tel.subscribe_position_velocity_ned(), 5.0)
            out.offboard_reached_m = math.dist((pv.position.north_m, pv.position.east_m, pv.position.down_m),
                                               (2.0, 0.0, -3.0))  # fmt: skip
            if out.offboard_reached_m >= SETTLED_M:
                inside_since = None
            elif inside_since is None:
                inside_since = loop.time()
            elif loop.time() - inside_since >= 2.0:
                out.offboard_settled = True
                break
        out.modes.append(await mode())
        await offboard.stop()
        await action.return_to_launch()
        await asyncio.sleep(0.5)
        out.modes.append(await mode())
        pv = await until(lambda pv: -pv.position.down_m < 0.1, 60.0)
        out.home_dist_after_rtl_m = math.hypot(pv.position.north_m, pv.position.east_m)
        await action.land()  # already down: accepted, and the landing ends disarmed
        out.landed_after = True


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_mavsdk_takeoff_hold_offboard_rtl_and_land() -> None:
    out = Actions()
    with running_vehicle() as api:
        asyncio.run(asyncio.wait_for(fly_actions(api, out), 180.0))
    print(f"MAVSDK actions: took off to {out.took_off_to_m:.2f} m; modes {out.modes}; offboard "
          f"{out.offboard_reached_m:.2f} m from its setpoint; RTL ended {out.home_dist_after_rtl_m:.2f} m "
          f"from home")  # fmt: skip
    assert abs(out.took_off_to_m - 3.0) < 0.3
    assert out.modes == [FlightMode.TAKEOFF, FlightMode.HOLD, FlightMode.OFFBOARD,
                         FlightMode.RETURN_TO_LAUNCH]  # fmt: skip
    assert out.offboard_settled, f"{out.offboard_reached_m:.2f} m off the setpoint after {OFFBOARD_LIMIT_S} s"
    assert out.home_dist_after_rtl_m < 1.0 and out.landed_after
