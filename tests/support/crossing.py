"""Two flyers whose plans cross at their margin, flown in the closed loop by one executor's
proximity stop and plan clock (`tests/test_plan_clearance.py`, `tests/test_proximity_pause.py`)."""

from __future__ import annotations

import math
from collections.abc import Callable

import msgspec

from common.bus.keys import Keys
from common.bus.messages import FramePose, PlanStep, PoseFrame
from common.bus.session import ZenohConfig
from common.domain.vehicle_model import VehicleModel
from services.executor.proximity import ProximityParams
from services.executor.service import ExecutorService
from services.executor.vehicle_controller import ControlParams, VehicleController
from services.sim.crazyflie.physics import SimFlyingCar
from tests.support.closed_loop import Mocap, plan_for, reference_steps, run
from tests.support.sent import SentMessages

MODEL = VehicleModel(margin=0.03)
DT = 0.01
CROSSING = (1.4, 0.45)
"""Where the two flyers' ways cross: cf1 flies along +x (the reference plan's flight), cf2 along +y."""
AHEAD_S = 0.57
"""s by which cf2 crosses before cf1: at 0.3 m/s each their centres come 0.121 m near, their bodies
(radius 0.045) 3.1 cm: the plans' 3 cm margin."""


def crossing_steps() -> dict[str, list[PlanStep]]:
    """cf1's reference plan, and cf2's: the same turned a quarter about `CROSSING` (its flight along
    +y through it) and AHEAD_S s earlier after its first wait."""
    steps = reference_steps(MODEL)
    cx, cy = CROSSING

    def turned(s: PlanStep, k: int) -> PlanStep:
        x, y, z = s.pos
        return msgspec.structs.replace(s, pos=(cx - (y - cy), cy + (x - cx), z), t=s.t - AHEAD_S * (k > 0))
    return {"cf1": steps, "cf2": [turned(s, k) for k, s in enumerate(steps)]}


def fly_crossing(proximity: ProximityParams, hold_cf2_at: float | None = None, react: float = 0.1,
                 gust: tuple[float, float] = (0.0, 0.0), gust_s: float = 0.2,
                 on_cycle: Callable[[ExecutorService, float], None] | None = None,
                 control: ControlParams | None = None, model: VehicleModel = MODEL,
                 steps: dict[str, list[PlanStep]] | None = None,
                 gust_when: Callable[[SimFlyingCar], bool] | None = None) -> tuple[ExecutorService, float]:
    """Both flyers in one executor, judged by its proximity stop every cycle on their bodies in
    ground truth, their plan's clock run by it, until cf1 is past the crossing (or held): the
    executor and the nearest their bodies came (m, ground truth). `hold_cf2_at`: cf2 stops short
    that far (m) before the crossing, as a vehicle its executor holds; `gust`: cf2 is blown at
    that acceleration (m/s^2, world x and y) for `gust_s` from 12 cm before the crossing;
    `on_cycle(svc, now)` runs before each cycle's proximity stop; `control`: the executor's and
    its controllers' (the defaults without); `model`, `steps`: other vehicles and plans than the
    crossing's (cf1's as long as the reference plan's), and `gust_when(cf2's body)` when cf2 is
    blown on them."""
    control = control or ControlParams()
    svc = ExecutorService("e1", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("clearance"),
                          proximity=proximity, control=control)
    svc._delay = SentMessages()  # (one executor: its clock's delay told to no one)
    svc.stats.add_latency(react, react)  # a loaded executor's pose-to-command p99 (80-vehicle soaks: 0.07-0.1 s)
    radius, height = model.body()
    loops = []
    for k, (vid, way) in enumerate((steps or crossing_steps()).items()):
        sim = SimFlyingCar(vid, model, pos=way[0].pos, yaw=0.0)
        ctrl = svc.controllers[vid] = VehicleController(vid, model, owner="e1", params=control,
                                                        tracking_pause=svc.tracking_pause(), count=svc.counters.inc)
        ctrl.load(plan := plan_for(vid, way, model, t0=0.5))
        svc.plans[vid] = plan
        loops.append((ctrl, sim, Mocap(seed=k)))
    (_, sim1, _), (cf2, sim2, _) = loops
    a1 = next(s for s in (steps or crossing_steps())["cf1"] if s.node == "a1")
    end = 0.5 + a1.t + (CROSSING[0] - a1.pos[0] + 0.4) / 0.3
    closest, pushed = math.inf, False
    k = 0
    while sim1.t < end + svc.controllers["cf1"].delay:  # (on the plan's clock: it may have stood)
        now = sim1.t
        svc.bodies.update(PoseFrame(t=now, seq=k, poses=[FramePose(s.vid, s.x, s.y, s.z, 0.0) for _c, s, _m in loops]))
        svc.bodies.settle(now)
        if hold_cf2_at is not None and not cf2.held and sim2.z > 0.4 and CROSSING[1] - sim2.y < hold_cf2_at:
            assert cf2.stop_short("held by its executor")
        blown = gust_when(sim2) if gust_when is not None else sim2.z > 0.4 and abs(CROSSING[1] - 0.12 - sim2.y) < 0.005
        if any(gust) and blown and not pushed:
            sim2.push(*gust, now + gust_s)
            pushed = gust_when is not None  # (once; the crossing's window blows it on while cf2 is in it)
        if on_cycle is not None:
            on_cycle(svc, now)
        svc._end_pauses(now)
        svc._stop_short(now)
        svc._run_clocks(now)
        for ctrl, sim, mocap in loops:
            run(ctrl, sim, now + DT, mocap=mocap)
        if abs(sim1.z - sim2.z) < height:
            closest = min(closest, math.hypot(sim1.x - sim2.x, sim1.y - sim2.y) - 2 * radius)
        k += 1
    return svc, closest
