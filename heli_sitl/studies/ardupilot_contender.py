"""ArduPilot's helicopter firmware as a contender: one scenario's trajectory flown in GUIDED.

Through processes, as a user flies it: ``heli-sitl up --firmware ardupilot`` (the plant as
ArduPilot's JSON physics, the scenario's airframe and world, the X-Cell tuning) and
:class:`ground.guided.GuidedFlight` in this process on the firmware's SERIAL1, paced
(:mod:`heli_plant.pacer`), then the flight read by the comparison's scorecard
(:mod:`heli_sitl.engine.guided_record`). The differences from the bench's own contenders, which the
report states: ArduPilot starts on the ground, takes off and reaches the trajectory's start
before t = 0 (the TLC and the PID start at the scenario's initial state, off the path), and
a trajectory that starts at ground level is flown ``lift_m`` higher. What each is told: the
TLC and the PID fly on the plant's exact state; ArduPilot flies on its own EKF3, fed by the
firmware's simulated sensors, which the plant's exact state drives and which are noise-free
as the bench configures them (SITL's defaults for the GPS, the IMU, and, by
``configs/ardupilot/xcell60.parm``, the barometers: ArduPilot's default barometer noise was
frozen into a 0.11 m height offset when the EKF's origin was set; docs/ardupilot-json.md).
Its estimate still lags and filters: within 0.01 m of the truth at rest and in the hover.

The firmware opens TCP 5760-5763 and UDP 9002-9008 (+ 10 N) on loopback: tests run this in
a private network namespace.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from autopilot.scenario import Scenario
from ground.client import GroundClient
from ground.guided import GuidedFlight, GuidedOptions, TrackingSummary
from heli_common.defaults import ports
from heli_common.wire.ardupilot_json import PACE_PORT_OFFSET
from heli_plant.ardupilot_link import port_for_instance
from heli_sitl.engine.guided_record import guided_record
from heli_sitl.launch.ardupilot import ArduPilotOptions, start
from heli_sitl.launch.children import stop_all
from heli_sitl.studies.scorecard import FlightScore, score

CONNECT_S = 60.0  # the firmware's first heartbeat (the plant imports, then the firmware boots)


@dataclass(frozen=True)
class ArduPilotFlight:
    score: FlightScore
    tracking: TrackingSummary  # of the firmware's own estimate, as the ground station saw it
    out: Path


def fly_ardupilot(
    scenario: str,
    plant: str,
    out: Path,
    *,
    firmware: Path,
    world: str | None = None,
    instance: int = 0,
    speedup: float = 10.0,
) -> ArduPilotFlight:
    """Fly ``scenario``'s trajectory with ArduPilot on ``plant`` (in ``world``); ``out`` keeps
    plant.csv, track.csv and the firmware's logs."""
    sc = Scenario.load(scenario)
    out.mkdir(parents=True, exist_ok=True)
    opts = ArduPilotOptions(firmware=firmware, instance=instance, plant=plant, world=world, scenario=scenario,
                            speedup=speedup, out=out)  # fmt: skip
    pace = port_for_instance(instance) + PACE_PORT_OFFSET
    log = (out / "guided.log").open("w")
    children = start(opts, echo=False)
    try:
        with GroundClient(ports(instance).gcs) as gc:
            gc.connect(CONNECT_S)
            flight = GuidedFlight(gc, sc.trajectory, GuidedOptions(pace_port=pace),
                                  track_csv=out / "track.csv",
                                  say=lambda line: print(line, file=log, flush=True))  # fmt: skip
            tracking = flight.run()
    finally:
        stop_all(children)
        log.close()
    rec = guided_record(out / "plant.csv", out / "track.csv", sc.trajectory.duration_s,
                        {"scenario": sc.run.name, "controller": "ardupilot"})  # fmt: skip
    return ArduPilotFlight(score(rec, sc), tracking, out)
