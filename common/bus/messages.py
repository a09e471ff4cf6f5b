"""Wire messages of the fleet (DESIGN.md): frozen msgspec Structs, msgpack on the wire.

Decoding is strict (`Codec.decode` raises `msgspec.DecodeError` or `ValidationError`); services
decode through `common.bus.pubsub`, which drops, counts and logs a malformed message once, never raising.
Times are seconds since the Unix epoch (``time.time()``) unless a field says otherwise.
"""

from __future__ import annotations

from typing import Generic, Literal, TypeVar

import msgspec

from common.domain.planfile import Plan, PlanGraph, PlanModel, Task
from common.domain.team_plan import Robot, Step, TeamPlan, Vec3
from common.domain.vehicle_model import EdgeKind, NodeKind

ControlMode = Literal["offboard", "onboard"]
"""How a vehicle flies (DESIGN.md "Vehicles"): `offboard` (paper 000: the executor's LQR sends
attitude and thrust) or `onboard` (motion capture streamed to its estimator, position setpoints to
its own controller)."""

MAX_MESSAGE_BYTES = 4 * 1024 * 1024
"""Payloads above this are rejected before decoding (a plan for 120 vehicles is well under 1 MiB)."""


class Pose(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Motion-capture pose of one rigid body (`vehicle/<vid>/pose`), stamped with its capture time."""

    vid: str
    t: float
    x: float
    y: float
    z: float
    yaw: float
    seq: int = 0
    source: str = "mocap"


class FramePose(msgspec.Struct, frozen=True, forbid_unknown_fields=True, array_like=True):
    """One vehicle's pose in a `PoseFrame`: position (m) and yaw (rad), map frame."""

    vid: str
    x: float
    y: float
    z: float
    yaw: float


class PoseFrame(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Every tracked vehicle's pose of one motion-capture frame (`mocap/frame`), stamped with the
    frame's capture time `t`: the hot path (DESIGN.md) carries one message per frame instead of one
    per vehicle. `seq` counts the bridge's frames; `source` is its backend; `arrived` is when the
    bridge had the frame (0: unknown): what comes before it is the capture system's own latency,
    what comes after is this software's."""

    t: float
    seq: int
    poses: list[FramePose]
    source: str = "mocap"
    arrived: float = 0.0

    def pose(self, p: FramePose) -> Pose:
        """`p` as a `Pose` of this frame."""
        return Pose(vid=p.vid, t=self.t, x=p.x, y=p.y, z=p.z, yaw=p.yaw, seq=self.seq, source=self.source)


class FlightSetpoint(msgspec.Struct, frozen=True, tag="flight", forbid_unknown_fields=True):
    """cflib `commander.send_setpoint` units: roll/pitch in degrees, yaw rate in deg/s, thrust 10001-60000."""

    roll: float
    pitch: float
    yawrate: float
    thrust: int


class WheelSetpoint(msgspec.Struct, frozen=True, tag="wheels", forbid_unknown_fields=True):
    """Wheel speeds in m/s at the wheel rim, positive forward (see docs/wheel_protocol.md)."""

    left: float
    right: float


class StopSetpoint(msgspec.Struct, frozen=True, tag="stop", forbid_unknown_fields=True):
    """Motors and wheels off: only for a vehicle on the ground (or an emergency cut)."""


class PositionSetpoint(msgspec.Struct, frozen=True, tag="position", forbid_unknown_fields=True):
    """Onboard control mode (DESIGN.md "Vehicles"): a full-state setpoint for the vehicle's own
    position controller (cflib `Commander.send_full_state_setpoint`, crazyflie-firmware
    crtp_commander_generic.c `fullStateDecoder`): position (m), velocity (m/s) and acceleration
    (m/s^2) feed-forward in the map frame, yaw (rad, CCW from +x) and yaw rate (rad/s)."""

    x: float
    y: float
    z: float
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0
    ax: float = 0.0
    ay: float = 0.0
    az: float = 0.0
    yaw: float = 0.0
    yaw_rate: float = 0.0


Setpoint = FlightSetpoint | PositionSetpoint | WheelSetpoint | StopSetpoint


class Cmd(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Executor -> gateway (`vehicle/<vid>/cmd`). `owner` is the executor instance that sent it."""

    vid: str
    owner: str
    seq: int
    t: float
    setpoint: Setpoint
    mode: str = ""


class CmdBatch(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One control cycle's commands of one executor for the vehicles of one gateway
    (`gateway/<instance>/cmd`): the hot path's batch (DESIGN.md). `t` is when it was sent; `pose_t`
    the capture time of the motion-capture frame the cycle fused (0: none) and `pose_arrived` when
    the mocap bridge had that frame (`PoseFrame.arrived`), for latency figures."""

    owner: str
    t: float
    cmds: list[Cmd]
    pose_t: float = 0.0
    pose_arrived: float = 0.0


class PlanStep(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One path entry with what an executor needs: node position and kind, and the kind of the edge
    that arrives here ("" for the first entry and for waits). `t` is relative to the mission start."""

    node: str
    t: float
    pos: tuple[float, float, float]
    kind: NodeKind
    edge: EdgeKind | Literal[""] = ""


class VehiclePlan(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A vehicle's timed path (`vehicle/<vid>/plan`). `t0` is the mission's common start (epoch s);
    0 means "not started yet" (the mission's start message sets it)."""

    vid: str
    mission: str
    map: str
    steps: list[PlanStep]
    model: PlanModel
    t0: float = 0.0
    rejoin: bool = False
    """This plan brings the vehicle, held, back into its mission (`Replan.rejoin`): its executor
    takes it although the vehicle is held (any other plan of a held vehicle is refused: one asked
    for before the hold, handed out after it, had a held vehicle drive on unplanned for)."""


class VehicleState(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Executor estimate, mode and progress (`vehicle/<vid>/state`)."""

    vid: str
    t: float
    owner: str
    mode: str
    x: float
    y: float
    z: float
    yaw: float
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0
    pose_ok: bool = True
    mission: str = ""
    step: int = 0
    steps: int = 0
    tracking_error: float = 0.0
    """m from the reference it follows (its plan's, or where a hold hovers it); 0 while it follows
    none: its pose stale, in an emergency descent, held on the ground."""
    charge_used_ah: float = 0.0
    arrived: bool = False
    landing: tuple[float, float, float] | None = None
    """Where a fault landing (abort, low battery, lost link) comes down; None otherwise. Another
    executor's fault landing keeps off it (`safe_landing_steps`)."""
    held: str = ""
    """Why the tracking guard or the proximity stop holds the vehicle where it is ("": it is not
    held); `rejoinable`: held for another's sake, by a fault that may clear, or late on its plan's
    way (not off it), the mission may bring it back. An executor that
    takes the vehicle over keeps the hold (the mission planned the others around it)."""
    rejoinable: bool = False
    delay: float = 0.0
    """How far its mission's plan clock stands behind the wall clock (s; `PlanDelay`): the plan's
    time is `t - t0 - delay`."""


class VehicleStates(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The states one executor published in one control cycle (`executor/<instance>/states`), as
    one message: the fleet's services (executors, missions) read these (32 vehicles' states at 20 Hz
    as a message each were three times 640 messages a second through the router). Each state is
    on `vehicle/<vid>/state` too, for tools."""

    owner: str
    t: float
    states: list[VehicleState]


class Telemetry(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Gateway -> everyone (`vehicle/<vid>/telemetry`): battery, link and firmware health.

    From the firmware's log block: `vbat` (V), `pm_state` (0 battery, 1 charging, 2 charged,
    3 low power), `supervisor` (`supervisor.info` bits, -1 unknown; docs/firmware_model.md), `rssi`
    (-dBm). From the gateway: `link_quality` (fraction of the log blocks that arrived), `sent`
    (packets handed to the link), `skipped` (packets not sent: not connected or link busy),
    `dropped` (the wheel app's lost app-channel packets), `cmd_rate_hz` (flight and wheel packets
    sent per second), `wheel_app_ok` (a flying car's wheel app answers its STATUS requests; always
    true without wheels). `capabilities`, `firmware`: what the vehicle is and runs; `control`: its
    control mode from the radios file (`offboard`: attitude setpoints from the executor's LQR;
    `onboard`: motion capture to its estimator, position setpoints to its own controller)."""

    vid: str
    t: float
    gateway: str
    vbat: float
    link_quality: float
    sent: int
    dropped: int
    cmd_rate_hz: float
    link_ok: bool = True
    owner: str = ""
    stale_cmd: bool = False
    skipped: int = 0
    supervisor: int = -1
    pm_state: int = 0
    rssi: float = 0.0
    capabilities: str = "fly+drive"
    firmware: str = ""
    estopped: bool = False
    wheel_app_ok: bool = True
    control: ControlMode = "offboard"


class EmergencyStop(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The operator's emergency stop (`estop`, operator role only): every gateway sends the
    supervisor's emergency stop to every vehicle (motors off, Locked). `release`: the gateways
    accept commands again and reboot the vehicles the stop locked."""

    t: float
    reason: str = ""
    release: bool = False


class VehicleEvent(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Something others must know (`vehicle/<vid>/event`): low battery, emergency landing, lost link."""

    vid: str
    t: float
    kind: str
    detail: str = ""
    node: str = ""
    rejoinable: bool = False
    """A `tracking_hold` for another's sake (the proximity stop, the reflex to a held vehicle) or of
    a vehicle stopped on the ground by a fault that may clear (a stale pose, a lost link) while its
    plan moved on, or held by the tracking guard late on its plan's way (not off it): the mission
    may bring it back into the plan once it stands still, seen, and its way is clear
    (`Replan.rejoin`)."""
    acted: bool = False
    """Its executor's report of what it does about a fault of its vehicle (it holds, lands, stops or
    hovers with nowhere clear to land), not another service's word on its health (a gateway's
    `link_lost`): a mission plans the others around the former (`MissionRunner.on_fault`)."""
    at: tuple[float, float, float] | None = None
    """Where the fault landing it reports comes down, unless straight down from where the vehicle
    is (`node`'s position; the only word of it for a spot beside the vehicle, no node of the graph:
    `ASIDE` in `services/executor/faults.py`)."""


class MocapBody(msgspec.Struct, frozen=True, forbid_unknown_fields=True, array_like=True):
    """One rigid body of a motion-capture frame: its name in the capture system, position (m), yaw (rad)."""

    name: str
    x: float
    y: float
    z: float
    yaw: float


class MocapFrame(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One frame of a (simulated) motion-capture system (`sim/mocap`): every body it saw, and the
    capture time `t` (epoch s). The mocap bridge's `sim` backend reads these as it reads a Vicon."""

    t: float
    bodies: list[MocapBody]


class SimTruth(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Ground truth of a simulated vehicle (`sim/truth/<vid>`)."""

    vid: str
    t: float
    x: float
    y: float
    z: float
    yaw: float
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    airborne: bool = False
    motors: bool = False
    vbat: float = 0.0
    charge_used_ah: float = 0.0


class SimTruthFrame(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Every vehicle's ground truth of one simulator instant (`sim/truths`), as one message: a
    mission judges the bodies' separation on these (32 vehicles' truths as 32 messages each
    instant, 1600 a second, were a fifth of a soak's router-and-mission process). Each truth is on
    `sim/truth/<vid>` too, for tools."""

    t: float
    truths: list[SimTruth]


SimFaultKind = Literal["mocap_dropout", "radio_blackout", "battery", "power_off", "power_on", "gust"]


class SimFault(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Fault injection into the simulators (`sim/fault/<vid>`; docs/reliability.md). Only the
    simulated motion capture and the simulated Crazyflies listen: real systems never see it.
    `mocap_dropout`: the body is not seen for `duration_s`; `radio_blackout`: the simulated radio
    loses every packet to and from the vehicle for `duration_s`; `battery`: the simulated battery
    has used `charge_used_ah` from now on; `power_off`: the vehicle is switched off (nothing answers
    on the radio, motors off) for `duration_s`, or until a `power_on` if 0, then boots as from a
    fresh power-on; `power_on`: switched on now; `gust`: wind pushes the body horizontally with
    `gust` (m/s^2, x and y in the world frame) for `duration_s` while it flies (`fleet sim fault`)."""

    vid: str
    kind: SimFaultKind
    duration_s: float = 0.0
    charge_used_ah: float = 0.0
    gust: tuple[float, float] = (0.0, 0.0)


class ServiceStats(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A service's health (`stats/<service>/<instance>`, every few seconds): `drops` is the total
    of its dropped messages (`common.bus.pubsub` drop counters), `counters` all its named counters,
    `figures` service-specific measurements (e.g. the executor's missed control deadlines)."""

    service: str
    instance: str
    t: float
    drops: int
    counters: dict[str, int]
    figures: dict[str, float] = {}


class TeamTask(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A ground-air team's task (paper 002, `PlanRequest(planner="collab", team=...)`): the drone
    `drone` from `drone_start` (x, y, z) to `goal` (x, y, z), helped by the UGV `ugv` starting at
    `ugv_start` (x, y, heading_deg; 0 = +x, counter-clockwise). `method`: PAD (002 §IV) or the
    full-dimensional ARA* baseline; `improve_s` bounds the improvement after the first solution."""

    drone: str
    ugv: str
    drone_start: Vec3
    ugv_start: Vec3
    goal: Vec3
    method: Literal["pad", "arastar"] = "pad"
    improve_s: float = 1.0


class Sweep(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A body that left its plan (issue 16): somewhere on the segment `p0` -> `p1` (m) over mission
    time [t0, t1] (s), or from t0 for ever if `rest` (a vehicle landing or coming to rest after a
    fault, as its executor does it); `reach` (m) widens it (a body that may wander off the segment)."""

    vid: str
    p0: Vec3
    p1: Vec3
    t0: float
    t1: float
    rest: bool = False
    reach: float = 0.0


class Replan(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Plan a running mission on from mission time `at` (issue 16). Every vehicle of `base` not in
    `left` keeps its path up to the first node it reaches at or after `at` and is planned on from
    there to its goal (or its new goal in `goals`: a task added while the others move; a vehicle
    that arrived starts again from its goal); the vehicles in `left` are gone from the plan and
    their bodies are `sweeps`. The answer's paths are whole (prefix + new suffix), in mission time.
    With `strand`, a vehicle whose goal is out of reach is given the nearest one it can reach (its
    switch node when on the ground: it stops there) instead of failing the replan; the answer's
    tasks carry the goals it was given. `rejoin`: vehicles that left held where they stopped and
    come back; each one's path in `base` is the one it left, shifted in time so that it is where
    the vehicle stands at `at` (their sweeps are not in `sweeps`); the replan fails, naming one,
    when its way to its switch node crosses a body of `sweeps`."""

    base: Plan
    at: float
    left: list[str] = []
    sweeps: list[Sweep] = []
    goals: dict[str, str] = {}
    strand: bool = False
    rejoin: list[str] = []


class PlanRequest(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Query payload of `planner/plan`. `map` is a shipped map name or a path readable by the planner.
    A team request (planner "collab") gives `team` and no `tasks`; `map` is a collab map. A `replan`
    request plans a running mission on (its `map` must be the base plan's; `planner` is the replanner:
    sipp, or ilp for a plan the ILP made). `reply_within`: how long (s) the requester waits for the
    reply from sending it (0: as long as it takes); the planner drops a request that waited that
    long behind others and plans one that waited part of it within what is left (`services/planner/service.py`)."""

    map: str
    tasks: dict[str, Task]
    planner: str = "sipp"
    mu: float = 0.5
    time_limit: float = 30.0
    mission: str = ""
    seed: int = 0
    team: TeamTask | None = None
    replan: Replan | None = None
    reply_within: float = 0.0


class PlanReply(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """`planner`: which planner made the plan (a replan's: the ILP, or SIPP after it found none);
    `failed_vehicle`: without a plan, the vehicle prioritized planning could not place, if one;
    `refused`: the vehicles of `Replan.rejoin` that cannot come back yet, each with why (every
    one of them: `failed_vehicle` is the first); `timed_out`: without a plan, a replan's time
    limit ended it with more left to try (asked again with more time, it may find one);
    `unplaceable`: without a plan, every vehicle of a replan that no priority order can place (its
    switch node claimed when it gets there: `failed_vehicle` is the first)."""

    ok: bool
    error: str = ""
    failed_vehicle: str = ""
    plan: Plan | None = None
    team_plan: TeamPlan | None = None
    planner: str = ""
    refused: dict[str, str] = {}
    timed_out: bool = False
    unplaceable: list[str] = []


class GraphRequest(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Query payload of `planner/graph`: the graph the planner builds from `map` (the base graph, or
    the uniform-time-step graph of the ILP)."""

    map: str
    uniform: bool = False


class GraphReply(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    ok: bool
    error: str = ""
    graph: PlanGraph | None = None


class VehicleTeamPlan(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One robot's copy of a team plan (`vehicle/<vid>/team_plan`, paper 002 §IV-E): it executes
    `plan.drone` or `plan.ugv` as `robot`, synchronised with `partner`. `t0` as in VehiclePlan."""

    vid: str
    mission: str
    robot: Robot
    partner: str
    plan: TeamPlan
    t0: float = 0.0


class TeamAction(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Executor -> robot (`vehicle/<vid>/action`): run step `index` of the robot's sequence (the
    controller action and the pose it should end in). Re-sent until the robot reports it done or
    failed; a robot runs each (mission, index, attempt) once and answers repeats with its status."""

    vid: str
    owner: str
    mission: str
    index: int
    step: Step
    t: float
    attempt: int = 0
    """0 for the plan's step; n for the executor's n-th re-try of it (an action that ended off its
    planned end under sensing noise, `services/executor/team_robots.py`): a new action."""


ActionState = Literal["started", "done", "failed"]


class ActionStatus(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Robot -> everyone (`vehicle/<vid>/action_status`): step `index` started, done or failed, and
    the robot's pose then (drone x, y, z; UGV x, y, heading_deg)."""

    vid: str
    mission: str
    index: int
    status: ActionState
    pose: Vec3
    t: float
    detail: str = ""
    attempt: int = 0
    """The `TeamAction.attempt` this reports on."""


class MissionStart(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """`mission/<id>/start`: every executor starts its vehicles' plans at `t0` (epoch s)."""

    mission: str
    t0: float
    vehicles: list[str]


class PlanDelay(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """`mission/<id>/delay`: how far the mission's plan clock stands behind the wall clock as
    executor `source` keeps it (`delay`, s, at wall time `t`), and the pace (0-1) its vehicles let
    it run at now (`common/flight/plan_clock.py`). Sent every control cycle while the pace is
    below 1 or the executor's own waiting grew (a late cycle), once when it is back to 1, and every
    second while a running mission's delay is not 0."""

    mission: str
    source: str
    delay: float
    pace: float
    t: float


class TaskAdd(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Query payload of `mission/<id>/add` (issue 16): give `vid`, a vehicle of the running mission
    (arrived, or still on its way), the new goal node `goal`; planned against the others' paths."""

    vid: str
    goal: str


class TaskAddReply(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """`ok` with the mission time (s) the vehicle is planned to reach its new goal, or the error."""

    ok: bool
    error: str = ""
    arrival_s: float = 0.0


class MissionAbort(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """`mission/<id>/abort`: every vehicle lands (flying) or stops (driving); with `vehicles`, only
    those (a replan could not place a driving vehicle: it stops where it is, the others fly on);
    with `hold` too, those are held where they are instead, hovering or stopped, for the mission's
    sake (a replan could not place a vehicle in the air: the mission may bring it back)."""

    mission: str
    reason: str
    vehicles: list[str] = []
    hold: bool = False


T = TypeVar("T")


class Codec(Generic[T]):
    """Strict msgpack codec for one message type."""

    def __init__(self, typ: type[T]) -> None:
        self.type = typ
        self._enc = msgspec.msgpack.Encoder()
        self._dec = msgspec.msgpack.Decoder(typ)

    def encode(self, msg: T) -> bytes:
        return self._enc.encode(msg)

    def decode(self, data: bytes | bytearray | memoryview) -> T:
        if len(data) > MAX_MESSAGE_BYTES:
            raise msgspec.ValidationError(f"message of {len(data)} bytes exceeds {MAX_MESSAGE_BYTES}")
        return self._dec.decode(data)
