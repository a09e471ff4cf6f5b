"""Closed loop of one vehicle without zenoh: `VehicleController` + `SimFlyingCar` + a noisy
100 Hz motion capture, stepped faster than real time. Used by the closed-loop tests and the
control-tick benchmark; `reference_steps` is the town-like path they fly (park, drive, take off,
fly, land, drive, park; paper 000 §VII-C) until maps/town.yaml provides real ones.
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import msgspec

from common.bus.messages import ControlMode, PlanStep, Pose, Setpoint, SimTruth, Telemetry, VehiclePlan
from common.domain.planfile import PlanModel
from common.domain.vehicle_model import EdgeKind, NodeKind, VehicleModel
from common.flight.modes import Mode
from services.executor.trajectory import RefSample
from services.executor.vehicle_controller import VehicleController
from services.sim.crazyflie.physics import SimFlyingCar
from tests.support.onboard_loop import FirmwareCar


@dataclass(frozen=True, slots=True)
class MocapNoise:
    """Gaussian pose noise (m, rad), gross outliers (probability per frame, size in m) and
    dropouts ((start, end) intervals of simulator time without poses)."""

    pos_std: float = 0.001
    yaw_std: float = math.radians(0.5)
    outlier_rate: float = 0.0
    outlier_size: float = 0.3
    dropouts: tuple[tuple[float, float], ...] = ()


class Mocap:
    """Turns ground truth into `Pose`s the way the mocap bridge would, with seeded noise."""

    def __init__(self, noise: MocapNoise = MocapNoise(), seed: int = 0) -> None:
        self.noise = noise
        self.rng = random.Random(seed)
        self.seq = 0

    def observe(self, truth: SimTruth) -> Pose | None:
        n = self.noise
        if any(a <= truth.t < b for a, b in n.dropouts):
            return None
        g = self.rng.gauss
        jump = n.outlier_size if self.rng.random() < n.outlier_rate else 0.0
        self.seq += 1
        return Pose(vid=truth.vid, t=truth.t, x=truth.x + g(0.0, n.pos_std) + jump, y=truth.y + g(0.0, n.pos_std),
                    z=truth.z + g(0.0, n.pos_std), yaw=truth.yaw + g(0.0, n.yaw_std), seq=self.seq)


@dataclass(frozen=True, slots=True)
class Record:
    """One control tick: simulator truth at the tick, the reference then and the controller's mode
    after the tick."""

    t: float
    truth: SimTruth
    ref: RefSample | None
    mode: Mode


def plan_for(vid: str, steps: Sequence[PlanStep], model: VehicleModel, t0: float = 0.0,
             mission: str = "sim") -> VehiclePlan:
    """A `VehiclePlan` carrying `model` (as the plan's PlanModel)."""
    plan_model = msgspec.convert(msgspec.to_builtins(model), PlanModel)
    return VehiclePlan(vid=vid, mission=mission, map="hand-built", steps=list(steps), model=plan_model, t0=t0)


def reference_steps(model: VehicleModel) -> list[PlanStep]:
    """Park -> road (0.1 m/s, a 90 degree turn, a wait) -> vertical takeoff to 0.5 m (0.2 m/s) ->
    1.5 m of flight (0.3 m/s) and a hover -> landing -> road -> park, timed by the model's speeds.
    Each leg is (node, position, node kind, arriving edge kind or "" for a wait, wait in s)."""
    legs: list[tuple[str, tuple[float, float, float], NodeKind, EdgeKind | Literal[""], float]] = [
        ("p0", (0.0, 0.0, 0.0), "parking", "", 1.0),
        ("r1", (0.15, 0.15, 0.0), "waypoint", "drive", 0.0),
        ("r2", (0.65, 0.15, 0.0), "waypoint", "drive", 0.0),
        ("r2", (0.65, 0.15, 0.0), "waypoint", "", 1.0),
        ("l1", (0.65, 0.45, 0.0), "land", "drive", 0.0),
        ("a1", (0.65, 0.45, 0.5), "air", "takeoff", 0.0),
        ("a2", (2.15, 0.45, 0.5), "air", "fly", 0.0),
        ("a2", (2.15, 0.45, 0.5), "air", "", 1.0),
        ("l2", (2.15, 0.45, 0.0), "land", "land", 0.0),
        ("r3", (2.15, 0.15, 0.0), "waypoint", "drive", 0.0),
        ("r4", (2.55, 0.15, 0.0), "waypoint", "drive", 0.0),
        ("p1", (2.70, 0.0, 0.0), "parking", "drive", 0.0),
    ]
    steps = [PlanStep(node="p0", t=0.0, pos=(0.0, 0.0, 0.0), kind="parking")]
    for node, pos, kind, edge, wait in legs:
        duration = math.dist(steps[-1].pos, pos) / model.edge_speed(edge) if edge else wait
        steps.append(PlanStep(node=node, t=round(steps[-1].t + duration, 6), pos=pos, kind=kind, edge=edge))
    return steps


def on_reference_plan(model: VehicleModel, t0: float = 0.5) -> tuple[list[PlanStep], SimFlyingCar, VehicleController]:
    """cf1 parked at the start of `reference_steps`' plan, its mission starting at `t0`: the plan's
    steps, the simulated vehicle and its controller with the plan loaded."""
    steps = reference_steps(model)
    sim = SimFlyingCar("cf1", model, pos=steps[0].pos, yaw=0.0)
    ctrl = VehicleController("cf1", model, owner="test")
    ctrl.load(plan_for("cf1", steps, model, t0=t0))
    return steps, sim, ctrl


def run(ctrl: VehicleController, sim: SimFlyingCar | FirmwareCar, until: float, mocap: Mocap | None = None,
        dt: float = 0.01, telemetry_every: int = 10,
        on_tick: Callable[[float], None] | None = None, control: ControlMode = "offboard",
        every: int = 1, delay_s: float = 0.0, act_delay_s: float = 0.0) -> list[Record]:
    """Step the loop from the simulator's clock to `until`: pose -> controller -> setpoint ->
    physics, with battery telemetry every `telemetry_every` ticks (saying control mode `control`;
    onboard needs `sim` to be a `tests.support.onboard_loop.FirmwareCar`). `on_tick(now)` runs
    before each tick (fault injection). A slow loop: poses reach the controller `delay_s` late and
    it ticks every `every` periods (the vehicle keeps the last setpoint meanwhile); a late link:
    each setpoint acts `act_delay_s` after its tick (the vehicle keeps the one before meanwhile)."""
    mocap = mocap or Mocap()
    records: list[Record] = []
    late: deque[Pose] = deque()
    sent: deque[tuple[float, Setpoint]] = deque()  # (when it acts, setpoint)
    setpoint = None
    k = 0
    while sim.t < until - 1e-9:
        now = sim.t
        if on_tick is not None:
            on_tick(now)
        truth = sim.truth()
        pose = mocap.observe(truth)
        if pose is not None:
            late.append(pose)
        while late and late[0].t <= now - delay_s + 1e-9:
            ctrl.on_pose(late.popleft())
        if telemetry_every and k % telemetry_every == 0:
            ctrl.on_telemetry(Telemetry(vid=sim.vid, t=now, gateway="sim", vbat=sim.battery.vbat,
                                        link_quality=1.0, sent=k, dropped=0,
                                        cmd_rate_hz=1.0 / dt, control=control), now)
        if k % every == 0:
            sent.append((now + act_delay_s, ctrl.tick(now).setpoint))
        while sent and sent[0][0] <= now + 1e-9:
            setpoint = sent.popleft()[1]
        if setpoint is not None:
            sim.apply(setpoint, now)
        records.append(Record(now, truth, ctrl.reference(now), ctrl.mode))
        sim.step(dt)
        k += 1
    return records
