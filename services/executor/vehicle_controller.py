"""The control stack of one vehicle (paper 000 §VI-B/§VI-C): trajectory, mode state machine,
estimator, pure pursuit on the ground, LQR in the air, fault handling. No I/O: the executor service
feeds it poses and telemetry and calls `tick` at the control rate; it returns the setpoint to send
and the state to publish.

All times are on one clock (epoch seconds in the fleet, the simulator's clock in tests); the plan's
step times are relative to the mission start `t0`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import NamedTuple

import msgspec
import numpy as np

from common.bus.messages import (
    Cmd,
    PlanStep,
    Pose,
    Setpoint,
    StopSetpoint,
    Telemetry,
    VehiclePlan,
    VehicleState,
    WheelSetpoint,
)
from common.crazyflie.thrust import WheelBase, thrust_command, to_flight_setpoint
from common.domain.mapfile import MapSpec
from common.domain.vehicle_model import G, VehicleModel
from common.flight.estimator import Estimate, EstimatorParams, KalmanBank, PoseEstimator
from common.flight.landing import REST_SPEED, LandInPlace
from common.flight.lqr import FlightLqr, LqrWeights
from common.flight.modes import AIRBORNE, GROUNDED, Mode, ModeMachine
from common.flight.plan_clock import ClockParams, pace_for
from services.executor import onboard
from services.executor.faults import (
    EmergencyDescent,
    FaultMonitor,
    FaultParams,
    clear_spot,
    in_column,
    in_way,
    safe_landing_steps,
    spot_beside,
)
from services.executor.pure_pursuit import PurePursuit, PursuitParams
from services.executor.trajectory import RefSample, Trajectory, TrajectoryParams

log = logging.getLogger(__name__)

NEAR_GROUND = frozenset({Mode.TAKING_OFF, Mode.LANDING, Mode.EMERGENCY_LANDING})
"""Modes whose ground (`VehicleController._ground_z`: where it took off, the node it lands on) is the
floor of its estimate (`PoseEstimator.floor`); in the others the floor is the lowest ground there is
(`VehicleController._lowest_ground`)."""


def lowest_ground(plan: VehiclePlan | None) -> float:
    """The lowest height (m) the ground under a vehicle can have: the motion-capture frame's floor
    (z = 0, where the maps put their ground) or the lowest point of its plan, if lower."""
    return min([0.0] + ([s.pos[2] for s in plan.steps] if plan is not None else []))


def _still(t: float, est: Estimate, yaw: float) -> RefSample:
    """A hovering reference at time `t` that holds the vehicle still where it is estimated, facing `yaw`."""
    return RefSample(t, est.x, est.y, est.z, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, yaw, 0.0, Mode.HOVERING)


MOVING = frozenset({Mode.DRIVING, Mode.TAKING_OFF, Mode.FLYING, Mode.LANDING})
"""Modes in which a vehicle moves on its plan (`VehicleController.motion`)."""
REPAUSE_S = 1.0
"""s after going on from a pause within which another for the same vehicle continues it (`VehicleController.pause`)."""
OWN_TRACKING = ""
"""`Pause.other` of a pause for the vehicle's own tracking (`VehicleController._pause_for_tracking`)."""
RESUME_S = 1.0
"""s over which a vehicle going on from a pause lets its plan's clock come back to full pace
(`VehicleController.go_on`, `_pace_clock`): at once, every reference of the mission jumped from
rest to its plan's speed and the flyers lagged theirs by a few centimetres as they caught up; in an
80-vehicle soak (2026-12-08) cf65 went on from a pause for cf14, both 2-3.4 cm off their
references a quarter of a second later, and their bodies met, 1.4 cm deep."""
PAUSABLE = frozenset({Mode.DRIVING, Mode.FLYING})
"""Modes in which a vehicle on its plan may pause (`VehicleController.pause`): not in its spot's column."""
IN_ITS_COLUMN = frozenset({Mode.TAKING_OFF, Mode.LANDING})
"""Modes in which a vehicle on its plan moves up or down its spot's column."""
PAST_PLAN = frozenset({Mode.DONE, Mode.EMERGENCY_LANDING})
"""Modes after which no plan is followed: at its end, or coming down blind. (These frozensets
also serve the control tick's speed: a `Mode.X` costs a tenth of a microsecond, through the enum
type's `__getattr__` hook, and a hovering vehicle's tick had about 25 in the lines it ran.)"""
ASTRAY_M = 0.05
"""m: a vehicle held hovering this far from its hover point with a body in its way back waits
where it is until the way is clear (`VehicleController._keep_off_the_way_back`: in an
80-vehicle soak two held flyers 22 cm apart, thrown 10-20 cm off their points in a 0.4 s stall
of their executor, flew back to them across each other's way and met head on, 4.6 cm deep)."""
YIELD_STEP_S = 0.05
"""s between the plan positions `VehicleController.yield_to` looks at (0.05 s is at most 1.5 cm of flight)."""
YIELD_UNSEEN_MAX = 0.5
"""m: the most `yield_to` widens its reach for a held vehicle's time unseen."""
YIELD_APPROACH = 0.005
"""m: how much nearer to the held vehicle its plan must bring a vehicle for it to yield (one whose
plan keeps its distance or leaves goes on: in a 32-vehicle soak cf07, stopped short of by cf16
behind it, yielded to cf16 and the two, closer than the plan's envelopes, could not be planned
back into the mission; `services/mission/rejoin.py`)."""
YIELD_BEHIND_S = 1.0
"""s of its plan behind now that `yield_to` looks at too: a vehicle may lag its reference by up to
the guard's burst (3x a 3 cm margin: 0.9 s of driving)."""


ACTUATION_S = 0.05
"""s from an executor's control tick to its command acting on the vehicle (the rest of its cycle,
the bus, the gateway's tick and radio slot, the link): the flight controller acts on the state
dead-reckoned to then and the reference of then (`_acting`; a Smith predictor's lead, the filter's
model of the commands left as it is: shifted in it too, a vehicle stronger than its model learned
its lift error wrong in the climb and came down blind at 3 m/s). Unled, a flyer's height loop swung
on the delay: in the closed loop with its commands acting 40 ms late on 30 ms old poses, 4.7 cm
peak to peak at up to 0.24 m/s, 60 ms late 15 cm; led by 50 ms, 0.4 and 4.4 cm; led with no
delay to lead, 0.2 cm (unled 0.3; `tests/test_closed_loop.py`). An 80-vehicle soak's flyers swung
+-3 cm at 0.3 m/s, and the proximity stop held them for it (docs/reliability.md)."""


class Pause(NamedTuple):
    """A pause of the mission's clock: a proximity pause (`VehicleController.pause`) or one for its
    own tracking (`OWN_TRACKING`, `VehicleController._pause_for_tracking`): why, for which other
    vehicle, since when (s; the first of the pauses it continues) and when its own stop began (s)."""

    why: str
    other: str
    since: float
    stopped: float


@dataclass(frozen=True)
class ControlParams:
    """dt: control period (s); actuation_s: how long after its tick a command acts on the vehicle
    (`ACTUATION_S`); touchdown_height: height above the landing node (m) below which,
    with the reference there too, a landing is complete and the motors stop; liftoff_height:
    height above which the flight integrators run; arrive_radius: m from the goal that counts as
    arrived; finish_s, finish_radius: a vehicle on the ground at its plan's end but short of its
    goal by less than `finish_radius` m (held up by the gateway while its executor was cut off,
    resumed behind its plan) drives on to the goal for up to `finish_s` s before it is done
    (straight: farther away, a straight line may leave the roads)."""

    dt: float = 0.01
    actuation_s: float = ACTUATION_S
    touchdown_height: float = 0.02
    liftoff_height: float = 0.01
    arrive_radius: float = 0.05
    finish_s: float = 10.0
    finish_radius: float = 0.5
    trajectory: TrajectoryParams = field(default_factory=TrajectoryParams)
    estimator: EstimatorParams = field(default_factory=EstimatorParams)
    pursuit: PursuitParams = field(default_factory=PursuitParams)
    lqr: LqrWeights = field(default_factory=LqrWeights)
    faults: FaultParams = field(default_factory=FaultParams)
    wheels: WheelBase = field(default_factory=WheelBase)
    clock: ClockParams = field(default_factory=ClockParams)


PRE_TURN_S = 2.0
"""s: a parked vehicle turns in place towards a drive starting this soon (`_turn_before_driving`)."""
REJOIN_LOOK_S, REJOIN_STEP_S = 10.0, 0.02
"""s ahead a plan that brings a held vehicle back is searched for the moment its reference comes
to the vehicle (the mission's switch time is 1-3 s ahead), and the search's step."""
ON_ITS_WAY_BACK_S = 10.0
"""s of its plan behind its reference (and 1 s ahead) where a vehicle the guard holds for its own
tracking may stand and still be on its way, late (`VehicleController._on_its_way`)."""
REPLAN_TOLERANCE = 0.01
"""m: how far a new plan's reference may be from the old one's at the switch (the corner blend at
the switch node; `TrajectoryParams.max_deviation` is 5 mm)."""
LANDING_RETRY_S = 0.5
"""s between the choices of a fault landing that found every node it may land on taken (it hovers
where it is meanwhile: `VehicleController._choose_landing`)."""
ASIDE_HOLD_S = 1.0
"""s an emergency descent with its poses back that comes down beside a body in its column holds its
height, besides the time its move there takes at flight speed (`_beside_a_body`): it comes down
once over the spot (a step of its reference in the horizontal settles in about a second)."""
BLIND_RETURNS = 1
"""How often in one mission a vehicle that came down blind in its take-off or landing may be held
for the mission to bring it back (`VehicleController._descent_complete`): one that loses its poses
there again stays down (in a soak on a starved machine cf08 came down blind in its take-off twice
and was brought back each time; its third flight ended in a blind descent 0.5 m from where it
began, onto a parked vehicle)."""


def _closest_pass(traj: Trajectory, here: tuple[float, float, float], start: float, reach: float) -> float | None:
    """When (mission time, from `start`, within `REJOIN_LOOK_S`) the reference of `traj` first
    passes `here` within `reach`: the nearest it comes on that pass; None if it does not."""
    best: tuple[float, float] | None = None
    for k in range(int(REJOIN_LOOK_S / REJOIN_STEP_S) + 1):
        t = start + k * REJOIN_STEP_S
        d = math.dist(here, traj.plan_position(min(t, traj.end_time)))
        if best is not None and d > best[0]:
            return best[1]  # moving away again: it passed
        if d <= reach and (best is None or d <= best[0]):
            best = (d, t)
    return None if best is None else best[1]


class VehicleController:
    """`load` a plan, `start` it (or load one with `t0`), feed `on_pose` / `on_telemetry`, and
    `tick(now)` at `params.dt` for the setpoint and state."""

    def __init__(self, vid: str, model: VehicleModel | None = None, owner: str = "",
                 params: ControlParams | None = None, bank: KalmanBank | None = None,
                 bodies: Callable[[], Iterable[tuple[float, float, float]]] | None = None,
                 ground: Callable[[], MapSpec | None] | None = None,
                 tracking_pause: tuple[float, float] | None = None,
                 count: Callable[[str], object] | None = None) -> None:
        """`bank`: the executor's, shared by its vehicles' estimators (`fuse_poses` a frame at once);
        `bodies`: where the other vehicles are, or land in a fault landing (a fault landing keeps
        off their columns: `safe_landing_steps`); `ground`: the plan's map as it is known, whose
        no-fly zones and obstacles a fault landing off the graph keeps off (None: not known);
        `tracking_pause`: (settle s, longest s) of a pause for its own tracking
        (`_pause_for_tracking`), given by an executor that runs its plan's clock; None: the guard
        holds at once; `count`: counts its pauses' ends by name (the executor's counters)."""
        self.vid = vid
        self.tracking_pause = tracking_pause
        self._count = count or (lambda _name: None)
        self._bodies = bodies or (lambda: ())
        self._ground = ground or (lambda: None)
        self.owner = owner
        self.params = params or ControlParams()
        self.model = model or VehicleModel()
        self.estimator = PoseEstimator(self.params.estimator, bank)
        self.pursuit = PurePursuit(self.params.wheels, self.params.pursuit)
        self.machine = ModeMachine(vid)
        self.plan: VehiclePlan | None = None
        self.pauses = 0
        """Pauses so far, proximity pauses (`pause`) and for its own tracking (`_pause_for_tracking`)."""
        self.holds = 0
        """Holds so far, each one to be reported (a refused return into the plan counts again:
        the mission had planned the others as if it came back)."""
        self._refused: VehiclePlan | None = None
        self._lowest_ground = lowest_ground(None)
        self.trajectory: Trajectory | None = None
        self.t0: float | None = None
        self.delay = 0.0
        """How far its mission's plan clock stands behind `now - t0` (s), and the pace it runs at
        (0-1): its executor's (`common/flight/plan_clock.py`); the plan's time is `now - t0 - delay`."""
        self.pace = 1.0
        self.seq = 0
        self.charge_used_ah = 0.0
        self.lqr = FlightLqr(self.model.mass, self.params.dt, self.params.lqr)
        self.faults = FaultMonitor(self.model, self.params.faults)
        self._seen: tuple[float, Estimate, RefSample | None] | None = None  # the last tick's `now`, estimate, reference
        self._reset_mission()

    def _reset_mission(self) -> None:
        self._active: Trajectory | None = self.trajectory  # the plan's, or a fault landing's
        self._fault_landing = False
        self._choose_again = False  # another executor's fault landing took its node (`landing_wanted_by`)
        self._landing_retry: float | None = None  # a fault landing hovers, every node taken: choose again then
        self._landing_paused: str | None = None  # its flight to its node headed into a body (`stop_short`)
        self.landing_wait = ""  # why a fault landing hovers to choose its node again (`_hover_to_choose_again`)
        self._landing_reason = ""  # why the fault landing (low battery, lost link, the abort)
        self._ground_z = 0.0  # height of the ground the vehicle took off from or lands on
        self._landing_end = 0.0
        self._hold_since: float | None = None
        self._descent: EmergencyDescent | None = None
        self._blind_returns = 0  # held where it came down blind, this mission (`_descent_complete`)
        self._abort: str | None = None
        self._last_tick: float | None = None
        self._guard_since: float | None = None  # since when the tracking error is past the margin
        self._paused: Pause | None = None  # the proximity pause (`pause`)
        self._pause_ref: RefSample | None = None  # where a paused flyer hovers, from its first tick paused
        self._pause_here = False  # paused, it stays where it stopped (not yet back onto its standing plan)
        self._last_pause: tuple[Pause, float] | None = None  # the last pause it went on from, and when
        self._resumed: float | None = None  # when it went on from its last pause (`RESUME_S`)
        self._guard_from = 0.0  # the guard sleeps until then (after a take-over)
        self.held: str | None = None
        """Why the tracking guard holds the vehicle (None: it does not)."""
        self.rejoinable = False
        """Held for another's sake (`stop_short`, `yield_to`), left behind by a fault that may
        clear (`_left_behind`), or held late on its plan's way (`_on_its_way`), not off it: the
        mission may bring it back."""
        self._rejoin: tuple[VehiclePlan, Trajectory, float] | None = None
        """The plan that brings a held vehicle back, its trajectory, and when (mission time) its
        reference comes to where the vehicle stands: it follows it from then on."""
        self._hover_ref: RefSample | None = None  # where a held vehicle hovers
        self._hovered_at: tuple[float, float] = (0.0, 0.0)  # where it began to hover (x, y): `keep_apart`
        self._waiting: RefSample | None = None  # where a held vehicle waits, its way back blocked
        self._yield: str | None = None  # another vehicle held where this one's plan goes: hold too
        self._stopped_at: tuple[float, float, float] | None = None  # where a fault on the ground stopped it
        self._slow_since: float | None = None  # since when it keeps the plan's clock below full pace
        self.clock_pace = 1.0
        """The pace this vehicle lets the plan's clock run at, as its last tick saw it (`_pace_clock`)."""

    # ---- inputs ---------------------------------------------------------------------------

    def load(self, plan: VehiclePlan) -> bool:
        """Take a new plan (replacing any other): the vehicle parks until the mission starts.
        Refused (False, logged) while airborne: a plan starts on the ground."""
        if plan.vid != self.vid:
            raise ValueError(f"plan for {plan.vid!r} loaded into the controller of {self.vid!r}")
        if self.machine.airborne:
            log.warning("%s: plan %r refused while %s; load it once landed", self.vid, plan.mission, self.mode)
            return False
        self.plan = plan
        self._lowest_ground = lowest_ground(plan)
        self.model = self.faults.model = plan.model
        self.lqr = FlightLqr(plan.model.mass, self.params.dt, self.params.lqr)
        est = self.estimator.estimate(self.estimator.t or 0.0)
        self.trajectory = Trajectory(plan.steps, self.params.trajectory,
                                     yaw0=None if est.stale else est.yaw)
        self.t0 = plan.t0 or None
        self.delay, self.pace = 0.0, 1.0
        self._reset_mission()
        self.machine.request(Mode.PARKED, self.estimator.t or 0.0, "plan loaded")
        return True

    def replan(self, plan: VehiclePlan, now: float) -> bool:
        """Switch to a new plan of the running mission without stopping (issue 16: the planner
        keeps every path up to the first node at or after the switch time, so the reference is the
        same until then). A vehicle at rest after its mission takes it as a new plan (`load`).
        Refused (False, logged) when the vehicle does not follow its plan any more (fault landing,
        held, aborted, landing) or the new plan's reference differs from the old one now, or, done,
        when the plan does not have it where it stands (`_off_plan`). A vehicle held `rejoinable`
        takes a plan that brings it back (`VehiclePlan.rejoin`, `_take_back`)."""
        if plan.vid != self.vid:
            raise ValueError(f"plan for {plan.vid!r} given to the controller of {self.vid!r}")
        old = self.trajectory
        if self._abort:
            log.warning("%s: new plan of %r refused: the mission is aborted (%s)", self.vid, plan.mission, self._abort)
            return False
        if self.mode == Mode.DONE and old is not None and self.t0 is not None and (off := self._off_plan(plan, now)):
            log.warning("%s: new plan of %r refused: it is done %s", self.vid, plan.mission, off)
            return False
        if self.mode == Mode.DONE or old is None or self.t0 is None:
            return self.load(plan)  # it parked facing the way it came: it turns before driving off
        if self.held and self.rejoinable and (plan.rejoin or self._rejoin is not None) and not self._fault_landing:
            return self._take_back(plan, old, now)  # (a plan after the one that brought it back replaces it)
        why = ("it is off its plan" if self._fault_landing or self._active is not old else
               "it is held" if self.held else "the mission is aborted" if self._abort else
               f"it is {self.mode}" if self.mode in (Mode.LANDING, Mode.EMERGENCY_LANDING) else "")
        new = Trajectory(plan.steps, self.params.trajectory, yaw0=old.sample(old.start_time).yaw)
        rel = self._rel(now)
        a, b = old.sample(rel), new.sample(rel)
        gap = math.dist((a.x, a.y, a.z), (b.x, b.y, b.z))
        if not why and gap > REPLAN_TOLERANCE:
            why = f"its reference would jump {gap:.3f} m"
        if why:
            log.warning("%s: new plan of %r refused: %s", self.vid, plan.mission, why)
            return False
        self.plan, self.trajectory, self._active = plan, new, new
        self._lowest_ground = lowest_ground(plan)
        log.info("%s: switched to a new plan of %r at %.2f s", self.vid, plan.mission, rel)
        return True

    def _off_plan(self, plan: VehiclePlan, now: float) -> str:
        """Why a vehicle done in its running mission may not take `plan` of it ("": it may): it is
        seen away from where the plan has it now (`guard_burst` x the margin: the tracking guard
        would hold it at once). A vehicle done at its goal takes a plan that gives it a new one
        (with its pose stale too: a motion-capture stall as the plan comes must not lose a lifelong
        mission its task; the guard judges it once it is seen); one done where a fault put it down
        (an emergency descent mid-flight) is out of the mission, and a replan asked for before it
        left still has it on its old way (in a 32-vehicle soak cf10, come down blind, took such a
        plan, tried to fly from where it stood and then drove 3 m from its reference until the
        guard held it)."""
        est = self.estimator.estimate(now)
        where = Trajectory(plan.steps, self.params.trajectory).plan_position(self._rel(now))
        off = math.dist((est.x, est.y, est.z), where)
        if not est.stale and off > self.params.faults.guard_burst * self.model.margin:
            return f"{off:.3f} m from where the plan has it"
        return ""

    def _take_back(self, plan: VehiclePlan, old: Trajectory, now: float) -> bool:
        """A held vehicle's way back into the mission's plan (`services/mission/rejoin.py`): it
        stays held until the new plan's reference passes where it stands, within the guard's limit
        (`_closest_pass`), then follows it (`_supervise`). Refused (False) when the
        reference does not come by: the hold stands and is reported again, since the mission
        planned the others as if it came back. A later plan of the mission while it waits (another
        fault's replan) replaces it. (Whether its way is clear is the planner's to judge,
        `Replan.rejoin`; should it head into a body all the same, the proximity stop holds it again.)"""
        assert self.t0 is not None
        new = Trajectory(plan.steps, self.params.trajectory, yaw0=old.sample(old.start_time).yaw)
        est, rel = self.estimator.estimate(now), self._rel(now)
        here = (est.x, est.y, est.z)
        reach = self.params.faults.guard_factor * self.model.margin
        meet = _closest_pass(new, here, rel, reach)
        if meet is None or est.stale or self.faults.link_lost(now):
            why = ("its pose is stale" if est.stale else "its link is lost" if self.faults.link_lost(now)
                   else f"its new plan does not come within {reach:.3f} m of where it stands")
            if self._refused is None or self._refused.steps != plan.steps:
                self._refused = plan
                self.holds += 1
                self.held = f"{self.held}; {why}"
                log.warning("%s: plan of %r that brings it back refused: %s; it stays held", self.vid, plan.mission, why)
            return False
        self._rejoin = (plan, new, meet)
        log.info("%s: back in the plan of %r: held until %.2f s, then following it", self.vid, plan.mission, meet)
        return True

    def _resume(self, now: float) -> None:
        """The new plan's reference has come to where the held vehicle stands: it follows it."""
        assert self._rejoin is not None
        plan, traj, _ = self._rejoin
        self.plan, self.trajectory, self._active = plan, traj, traj
        self._lowest_ground = lowest_ground(plan)
        self.held, self.rejoinable, self._rejoin = None, False, None
        self._yield = self._hover_ref = self._waiting = self._guard_since = None
        log.info("%s: follows its plan again", self.vid)

    def take_over(self, state: VehicleState, now: float, pose: Pose | None = None) -> None:
        """Continue controlling a vehicle another executor was controlling (it died): adopt its
        mode and charge estimate, and start the estimator at rest from the newer of its last state
        and `pose` (its latest motion-capture pose), so the first ticks are not blind. After a
        partition the state is a lease old: fusing the pose after it would read the vehicle's
        displacement meanwhile (the gateway landing it) as a velocity, and the controller chased
        that velocity (a resumed vehicle climbed to 1.5 m and landed 1.5 m off the map). A fault
        landing in progress is restarted towards the nearest safe point; a held vehicle stays held
        (`_keep_hold`)."""
        try:
            mode = Mode(state.mode)
        except ValueError:
            log.warning("%s: unknown mode %r at take-over; assuming parked", self.vid, state.mode)
            mode = Mode.PARKED
        self.charge_used_ah = state.charge_used_ah
        # the vehicle drifted (or its gateway landed it) while it had no owner: the guard waits
        # `guard_rejoin_s` for it to get back onto its reference
        self._guard_from = now + self.params.faults.guard_rejoin_s
        self.estimator.reset(pose if pose is not None and pose.t > state.t else
                             Pose(vid=self.vid, t=state.t, x=state.x, y=state.y, z=state.z, yaw=state.yaw,
                                  source="take-over"))
        rel = None if self.t0 is None or self._active is None else self._rel(now)
        planned = None if rel is None else self._active.modes[self._active.segment(rel)]
        fault_landing = mode == Mode.LANDING and planned != Mode.LANDING
        self.machine.resume(Mode.FLYING if fault_landing else mode, now, f"taken over from {state.owner}")
        if mode in AIRBORNE:
            self.lqr.reset()
        if mode == Mode.EMERGENCY_LANDING:
            self._descent = self._emergency_descent(now)
        elif rel is not None and fault_landing:
            self._begin_safe_landing(now, rel, self.estimator.estimate(now), "landing continued after take-over")
        elif rel is not None and mode == Mode.LANDING:
            self._enter_landing(self._active, rel)
        if rel is not None and (state.held or mode == Mode.HOVERING):
            self._keep_hold(state, rel, now)

    def _keep_hold(self, state: VehicleState, rel: float, now: float) -> None:
        """A vehicle held where it is (or hovering for a fault landing with nowhere clear to land)
        when it was taken over stays held there: the mission planned the others around it (its plan
        would take it back into their space). The hold is reported again by this executor."""
        self.held = state.held or f"hovering when taken over from {state.owner}"
        self.rejoinable = state.rejoinable
        self.holds += 1
        if self.machine.airborne:
            self._hover_ref = self._hover_here(rel, self.estimator.estimate(now))
        log.warning("%s: taken over held: %s", self.vid, self.held)

    def start(self, t0: float) -> None:
        """The mission starts at `t0` (the plan's step times are relative to it)."""
        self.t0 = t0

    def abort(self, reason: str) -> None:
        """Mission abort: land at the nearest safe point if airborne, stop if on the ground."""
        self._abort = reason

    def on_pose(self, pose: Pose) -> bool:
        """Fuse a motion-capture pose; False if dropped or rejected as an outlier."""
        return self.estimator.update(pose)

    def on_telemetry(self, tel: Telemetry, now: float) -> None:
        self.faults.on_telemetry(tel, now)

    @property
    def mode(self) -> Mode:
        return self.machine.mode

    @property
    def emergency_aside(self) -> tuple[float, float, float] | None:
        """Where on the ground an emergency descent comes down beside a body in its column
        (`_beside_a_body`), once chosen; None: where it is, or over its column's foot."""
        descent = self._descent
        return descent.aside if descent is not None and self.mode == Mode.EMERGENCY_LANDING else None

    @property
    def landing_step(self) -> PlanStep | None:
        """The last entry of a fault landing's path (low battery, lost link, abort): the ground node
        it is heading for, or a spot off the graph, with its position; None while the vehicle
        follows its plan (or a planned landing ends the mission)."""
        if not self._fault_landing or self._active is None or self._active is self.trajectory:
            return None
        return self._active.steps[-1]

    def _rel(self, now: float) -> float:
        """The plan's time at `now` (s since the mission's start, on its plan clock)."""
        assert self.t0 is not None
        return now - self.t0 - self.delay

    def reference(self, now: float, ahead: float = 0.0) -> RefSample | None:
        """The reference being followed at `now`, or `ahead` s of the wall clock later (the plan's,
        or a fault landing's, or where the tracking guard holds it), its velocity and acceleration
        scaled to the plan clock's pace; None before the mission starts."""
        if self._active is None or self.t0 is None:
            return None
        if self._hover_ref is not None:
            return self._waiting or self._hover_ref
        if self._pause_ref is not None:
            return self._pause_ref
        p = self.pace
        ref = self._active.sample(self._rel(now) + ahead * p)
        if p >= 1.0:
            return ref
        a = p * p
        return msgspec.structs.replace(ref, vx=p * ref.vx, vy=p * ref.vy, vz=p * ref.vz, ax=a * ref.ax, ay=a * ref.ay,
                                       az=a * ref.az, yaw_rate=p * ref.yaw_rate)

    # ---- the control tick -----------------------------------------------------------------

    def tick(self, now: float) -> Cmd:
        """One control step at `now`: supervise the mode, run its controller, account the charge.
        `state()` tells what the step saw (built only when asked: the executor publishes one
        state in five ticks)."""
        self.estimator.floor = self._ground_z if self.machine.mode in NEAR_GROUND else self._lowest_ground
        est = self.estimator.estimate(now)
        dt = 0.0 if self._last_tick is None else min(max(now - self._last_tick, 0.0), 0.1)
        self._last_tick = now
        ref: RefSample | None = None
        before = self.machine.mode
        if self._active is not None and self.t0 is not None:
            active, ref = self._active, self.reference(now)
            self._supervise(now, self._rel(now), est, ref)
            if self._paused is not None and not self._may_yield():  # it left its plan (a fault landing,
                self._paused = self._pause_ref = None  # an abort, a hold): no pause, its clock runs on
            self._pace_clock(now, est, ref)
            if self._active is not active or self._hover_ref is not None or self._pause_ref is not None:
                ref = self.reference(now)
        setpoint = self._control(now, est, ref, before)
        self.charge_used_ah += self.model.charge_ah(self._power(ref), dt)
        self.seq += 1
        self._seen = (now, est, ref)
        return Cmd(vid=self.vid, owner=self.owner, seq=self.seq, t=now, setpoint=setpoint,
                   mode=str(self.machine.mode))

    def _supervise(self, now: float, rel: float, est: Estimate, ref: RefSample | None) -> None:
        m = self.machine
        if m.mode in PAST_PLAN:
            return
        low = self.faults.low_battery(self.charge_used_ah, now)
        link = self.faults.link_lost(now)
        if m.airborne:
            if est.stale:
                vertical = m.mode == Mode.TAKING_OFF or (m.mode == Mode.LANDING and not self._fault_landing)
                was = m.mode
                if m.request(Mode.EMERGENCY_LANDING, now, "pose stale in the air"):
                    self._descent = self._emergency_descent(now, self._column_foot(ref, was) if vertical else None,
                                                            (ref.x, ref.y) if vertical and ref is not None else None)
                return
            reason = "low battery" if low else "link lost" if link else self._abort
            if reason and not self._fault_landing:
                self._begin_safe_landing(now, rel, est, reason)
                return
            if self._landing_paused is not None:
                self._pause_landing(now, rel, est, self._landing_paused)
            if self._choose_again and self._active is not None:
                self._choose_again = False
                if m.mode == Mode.LANDING and rel < self._active.steps[-2].t:  # not above its node yet
                    log.info("%s: gives its landing node up to a vehicle of another executor", self.vid)
                    self._choose_landing(now, rel, est)
            if self._landing_retry is not None and now >= self._landing_retry:
                self._choose_landing(now, rel, est)
            if self.held and self._rejoin is not None and rel >= self._rejoin[2]:
                self._resume(now)
            if (self._fault_landing and m.mode == Mode.LANDING and self.landing_step is None
                    and self._planned_landing_blocked(est, ref)):
                log.warning("%s: %s while landing, a body below it: lands elsewhere", self.vid, self._landing_reason)
                self._choose_landing(now, rel, est)
                return
            if self.held:
                self._keep_off_the_way_back(est)
            if self._fault_landing or self.held or (m.mode == Mode.LANDING and rel >= self._landing_end):
                return  # a landing lasts until touchdown (see `_control`), even past its plan time
            if self._yield is not None and ref is not None:
                self._hold(now, est, ref, self._yield, rejoinable=True)
                return
            if self._still_paused(now, est, ref):
                return
            if self._guard(now, est, ref):
                return
            self._follow_plan(now, rel, est)
            return
        if self._abort or low:
            m.request(Mode.DONE, now, self._abort or "low battery")
            return
        if self.held and self._rejoin is not None and rel >= self._rejoin[2]:
            self._resume(now)
        if self.held:
            return  # stopped until the mission brings it back (`_take_back`), if it does
        if self._yield is not None and ref is not None:
            self._hold(now, est, ref, self._yield, rejoinable=True)
            return
        if self._still_paused(now, est, ref):
            return
        if m.mode == Mode.DRIVING and self._guard(now, est, ref):
            return
        if est.stale or link:
            if m.mode != Mode.HOLDING:
                self._hold_since = now
                self._stopped_at = self._stopped_position(est)
                m.request(Mode.HOLDING, now, "pose stale" if est.stale else "link lost")
            elif now - (self._hold_since or now) > self.params.faults.max_hold_s:
                m.request(Mode.DONE, now, "held too long, plan given up")
            else:
                self._left_behind(now, est, ref)
            return
        self._follow_plan(now, rel, est)

    def _pace_clock(self, now: float, est: Estimate, ref: RefSample | None) -> None:
        """The pace this vehicle lets its plan's clock run at (`clock_pace`, `pace_for`): by how far
        it is behind its reference along its way while it drives or flies on its plan (`_behind`),
        by its horizontal distance in a take-off or landing (late in its own spot's column, as the
        guard judges it), or, stopped on the ground by a stale
        pose or a lost link, by how far the reference is from where it stopped; full pace otherwise
        (parked, held, in a fault landing). One that has kept the clock below full pace for
        `ClockParams.max_wait_s` is held (the tracking guard's hold: reported, the mission plans
        around it), rejoinable if stopped by a fault that may clear. Paused, it stands the clock;
        going on, it brings it back to full pace over `RESUME_S`."""
        if self._paused is not None:
            self.clock_pace = 0.0
            return
        self._pace_by_tracking(now, est, ref)
        if self._resumed is not None:
            ramp = (now - self._resumed) / RESUME_S
            if ramp >= 1.0 or self.held or not self._may_yield():
                self._resumed = None
            else:
                self.clock_pace = min(self.clock_pace, ramp)

    def _pace_by_tracking(self, now: float, est: Estimate, ref: RefSample | None) -> None:
        """`_pace_clock` by how far the vehicle is behind its reference (or its stop)."""
        c, mode = self.params.clock, self.machine.mode
        error = None
        if ((mode in MOVING or mode == Mode.HOLDING) and c.enabled and ref is not None and self._hover_ref is None
                and now >= self._guard_from and self._may_yield()):
            if mode == Mode.HOLDING:
                error = None if self._stopped_at is None else math.dist(self._stopped_at, (ref.x, ref.y, ref.z))
            elif mode in MOVING and not est.stale:
                error = (math.hypot(est.x - ref.x, est.y - ref.y) if mode in IN_ITS_COLUMN
                         else self._behind(est, ref))
        pace = 1.0 if error is None else pace_for(error, self.model.margin, c)
        self.clock_pace = pace
        if pace >= 1.0:
            self._slow_since = None
            return
        since = self._slow_since = self._slow_since if self._slow_since is not None else now
        if now - since >= c.max_wait_s and ref is not None:
            self.clock_pace, self._slow_since = 1.0, None
            late, way = (True, "") if mode == Mode.HOLDING else self._on_its_way(est, ref)
            self._hold(now, est, ref, f"kept its plan's clock waiting {now - since:.1f} s, {error:.3f} m from its "
                                      f"reference in {mode}{way}", rejoinable=late)

    def _behind(self, est: Estimate, ref: RefSample) -> float:
        """How far the vehicle is behind its reference along the plan's way there (at a wait, the
        way it came in; m, 0 when ahead). Sideways or ahead it is off its plan, not late, and waiting
        does not bring it back: pure pursuit holds a resting reference within `hold_radius` (a
        driver 2.7 cm beside a reference that stood still kept the clock waiting 5 s), and a flyer
        whose commands no longer reach it (a lost link, levelled by its firmware) would only fly on
        past a reference that stopped for it."""
        traj = self._active
        assert traj is not None
        way = traj.ways[traj.segment(ref.t)]
        if way is None:
            return math.dist((ref.x, ref.y, ref.z), (est.x, est.y, est.z))
        return max((ref.x - est.x) * way[0] + (ref.y - est.y) * way[1] + (ref.z - est.z) * way[2], 0.0)

    def _guard(self, now: float, est: Estimate, ref: RefSample | None) -> bool:
        """The tracking guard (`FaultParams`): hold the vehicle where it is if its estimated error
        left the plan's margin; whether it holds."""
        f, margin = self.params.faults, self.model.margin
        if not f.guard or margin <= 0.0 or ref is None or est.stale:
            self._guard_since = None
            return False
        if self.machine.mode == Mode.TAKING_OFF:  # (climbing late in its own spot's column: harmless)
            error = math.dist((est.x, est.y), (ref.x, ref.y))
            height, planned = est.z - self._ground_z, ref.z - self._ground_z
            if height < self.model.height < planned - f.guard_burst * margin and now >= self._guard_from:
                # ... unless its plan has it well clear of the ground layer, which others may now cross
                late, way = self._on_its_way(est, ref)
                self._hold(now, est, ref, f"{height:.3f} m up in its take-off, its plan {planned:.3f} m: "
                                          f"still among the vehicles on the ground{way}", late)
                return True
        else:
            error = math.dist((est.x, est.y, est.z), (ref.x, ref.y, ref.z))
        limit = f.guard_factor * margin
        if error <= limit or now < self._guard_from:  # (taken over off its reference: it gets back first)
            self._guard_since = None
            return False
        last = self.machine.history[-1] if self.machine.history else None
        if last is not None and last.dst == Mode.DRIVING and now - last.t < f.guard_drive_start_s:
            return False  # turning in place on its spot towards its first edge (pure pursuit)
        since = self._guard_since = self._guard_since if self._guard_since is not None else now
        if error <= f.guard_burst * margin and now - since < f.guard_s:
            return False
        why = f"tracking error {error:.3f} m past the plan's margin {margin:.3f} m for {now - since:.2f} s in {self.machine.mode}"
        if error <= f.guard_burst * margin and self._pause_for_tracking(why, now):
            return True
        late, way = self._on_its_way(est, ref)
        self._hold(now, est, ref, why + way, late)
        return True

    def _pause_for_tracking(self, why: str, now: float) -> bool:
        """A flyer on its plan the guard would hold for its own tracking (past `guard_factor` x the
        margin for `guard_s`, not past `guard_burst` x) pauses its mission instead, when its
        executor runs the plan's clock (`tracking_pause`): the clock stands, every vehicle of the
        mission comes to rest where its plan has it at one time, and this one flies back onto its
        plan's place and goes on once within the margin of it (`_judge_tracking_pause`). The two
        10-minute 80-vehicle soaks of 2026-12-08 that failed a mission and the 64-vehicle one of the
        night before began with a flyer held 11-16 cm off its plan in cruise (a late loop's height
        swing where traced), after which the yields and replans around it could not place everyone.
        Whether it pauses."""
        if (self.tracking_pause is None or self.machine.mode != Mode.FLYING or self._hover_ref is not None
                or self._active is not self.trajectory or not self._may_yield()):
            return False
        self._begin_pause(why, OWN_TRACKING, now, here=False)
        self._count("tracking_paused")
        return True

    def _judge_tracking_pause(self, now: float, est: Estimate, ref: RefSample) -> bool:
        """Paused for its own tracking (`_pause_for_tracking`): it goes on once at least the settle
        time paused and within the plan's margin of its (standing) reference; held as the guard
        would have held it once paused for the longest time (the pauses it continues counted) or
        off by more than `guard_burst` x the margin. Whether this tick's supervision ends here
        (still paused, or held now)."""
        pause, f, margin = self._paused, self.params.faults, self.model.margin
        assert pause is not None and self.tracking_pause is not None
        settle, longest = self.tracking_pause
        error = math.dist((est.x, est.y, est.z), (ref.x, ref.y, ref.z))
        if error > f.guard_burst * margin or now - pause.since >= longest:
            self._count("tracking_pause_held")
            late, way = self._on_its_way(est, ref)
            self._hold(now, est, ref, f"{pause.why}; paused {now - pause.since:.1f} s, {error:.3f} m from its "
                                      f"plan's place{way}", late)
            return True
        if now - pause.stopped >= settle and error <= margin:
            self._count("tracking_pause_ended")
            self.go_on(now)
            return False
        return True

    def _on_its_way(self, est: Estimate, ref: RefSample) -> tuple[bool, str]:
        """Whether the vehicle stands within the guard's limit of its plan's way (`ON_ITS_WAY_BACK_S`
        behind its reference to 1 s ahead): late on its way, not off it; and what to add to its
        hold's report. A vehicle the guard holds so (a starved loop, a stalled take-off) is
        rejoinable: once it stands still, its loop fed again, the mission brings it back on its way
        (`services/mission/rejoin.py`, `_take_back`, which meets it within the same limit); one
        pushed off its way stays out. (In 32-vehicle soaks on a loaded machine the flyers the guard
        held late stayed out, and the missions failed with every other vehicle arrived.)"""
        traj = self._active
        if traj is None:
            return False, ""
        here, reach = (est.x, est.y, est.z), self.params.faults.guard_factor * self.model.margin
        start, end = max(ref.t - ON_ITS_WAY_BACK_S, 0.0), min(ref.t + 1.0, traj.end_time)
        off = min(math.dist(here, traj.plan_position(start + k * YIELD_STEP_S))
                  for k in range(int((end - start) / YIELD_STEP_S) + 1))
        return off <= reach, f"; {off:.3f} m from its plan's way: {'late on it' if off <= reach else 'off it'}"

    def _stopped_position(self, est: Estimate) -> tuple[float, float, float]:
        """Where a fault on the ground stops the vehicle: its estimate (dead-reckoned since the last
        pose: it drove there), or, with no pose ever, where its plan starts (nothing has driven it;
        the filter's empty state is the origin, which once held a vehicle that motion capture found
        late for good before its mission started)."""
        if math.isfinite(est.pos_std) or self._active is None:
            return (est.x, est.y, est.z)
        start = self._active.sample(0.0)
        return (start.x, start.y, start.z)

    def _left_behind(self, now: float, est: Estimate, ref: RefSample | None) -> None:
        """Stopped on the ground for a fault that may clear (stale pose, lost link) while its plan
        runs on: once the plan's reference is `guard_factor` x the margin away from where the
        vehicle stopped (known without fresh poses: it does not move, so no tracking noise to
        allow for, and no `guard_s` to wait), the others' plans no longer fit it, so it is held for
        good and reported like any vehicle the guard holds. (At `guard_burst` x, 9 cm, in a
        32-vehicle soak a neighbour on time drove into it while the report travelled.)"""
        f, margin = self.params.faults, self.model.margin
        if not f.guard or margin <= 0.0 or ref is None or self._stopped_at is None or now < self._guard_from:
            return  # (taken over: the guard waits for it to get back onto its reference)
        error = math.dist(self._stopped_at, (ref.x, ref.y, ref.z))
        if error > f.guard_factor * margin:  # (once the fault clears, the mission may bring it back)
            self._hold(now, est, ref, f"its plan moved on {error:.3f} m while it was stopped "
                                      f"({self.machine.history[-1].reason if self.machine.history else 'holding'})",
                       rejoinable=True)

    def _hold(self, now: float, est: Estimate, ref: RefSample, why: str, rejoinable: bool = False) -> None:
        """Hold the vehicle where it is for the rest of the mission, hovering or stopped on the
        ground, unless (`rejoinable`: held for another's sake, left behind by a fault that may
        clear, or held late on its plan's way: `_on_its_way`) the mission brings it back."""
        self.held, self.rejoinable = why, rejoinable
        self.holds += 1
        self._paused = self._pause_ref = None
        if self.machine.airborne:
            self._hover_ref = self._hover_here(ref.t, est)
            self.machine.request(Mode.HOVERING, now, why)
        elif self.machine.mode != Mode.HOLDING:
            self.machine.request(Mode.HOLDING, now, why)
        log.warning("%s: held by the tracking guard: %s", self.vid, why)

    def _hover_here(self, t: float, est: Estimate) -> RefSample:
        """A reference that holds the vehicle still where it is estimated, facing as it does."""
        self._hovered_at, self._waiting = (est.x, est.y), None
        return _still(t, est, est.yaw)

    def _keep_off_the_way_back(self, est: Estimate) -> None:
        """A vehicle held hovering that finds itself more than `ASTRAY_M` from its hover point (a
        stall of its loop threw it off) with another body on its way back there (`in_way`, between
        the two: one past the point is the standoff's, `keep_apart`) waits where it is until the
        way is clear, then goes back."""
        at = self.held_hover()
        if at is None or est.stale or self._hover_ref is None:
            return
        here = (est.x, est.y, est.z)
        if self._waiting is None and math.dist(here, at) <= ASTRAY_M:
            return
        body = next((b for b in self._bodies() if in_way(here, at, b, self.model, beyond=False)), None)
        if body is not None and self._waiting is None:
            log.warning("%s: held, %.3f m off its hover point, a body at (%.2f, %.2f, %.2f) in its way back: "
                        "waits where it is", self.vid, math.dist(here, at), *body)
            self._waiting = _still(self._hover_ref.t, est, self._hover_ref.yaw)
        elif body is None and self._waiting is not None:
            log.warning("%s: held, its way back to its hover point clear: goes back", self.vid)
            self._waiting = None

    def held_hover(self) -> tuple[float, float, float] | None:
        """Where a vehicle held in the air hovers (its hover reference), for `keep_apart`; None
        when it is not held hovering (a fault landing's pause is not a hold: it goes on)."""
        ref = self._hover_ref
        if self.held is None or ref is None or self.machine.mode != Mode.HOVERING:
            return None
        return ref.x, ref.y, ref.z

    def keep_apart(self, dx: float, dy: float, reach: float) -> None:
        """Move the held hover's point by (`dx`, `dy`) m, level, to at most `reach` m from where the
        vehicle began to hover (the executor's `_keep_apart`: a body too near, `ProximityParams.standoff`)."""
        ref = self._hover_ref
        if ref is None:
            return
        x0, y0 = self._hovered_at
        if (ref.x, ref.y) == (x0, y0):
            log.warning("%s: held hovering too near another body: moves its hover point away", self.vid)
        ox, oy = ref.x + dx - x0, ref.y + dy - y0
        scale = min(1.0, reach / max(math.hypot(ox, oy), 1e-12))
        self._hover_ref = msgspec.structs.replace(ref, x=x0 + scale * ox, y=y0 + scale * oy)

    def yield_to(self, vid: str, pos: tuple[float, float, float], now: float, unseen_s: float = 0.0,
                 descending: bool = False) -> bool:
        """The fleet's reflex to `vid`, held by the tracking guard at `pos` (issue 15), or, when
        `descending`, coming straight down from there (an emergency landing: anywhere in the column
        below `pos`): this vehicle holds too (at its next tick, reported as `tracking_hold`) if its
        plan brings its body within reach of `vid`'s in the next `yield_s` s: both envelopes, plus the
        guard's allowance for this one's tracking, plus the way `vid` may have gone in the `unseen_s`
        s between its pose `pos` and its hold (stopped on a stale pose, it drove on blind: 14 cm past
        its last pose in a 32-vehicle soak, where a neighbour drove into it), at the fastest of its
        speeds, up to `YIELD_UNSEEN_MAX`. (A vehicle that came down in an emergency landing on a
        road was driven into by one on its plan before the replan around it switched: a 32-vehicle
        soak, 7.6 cm deep.) Not if its plan does not bring it nearer to `vid` than it is
        (`YIELD_APPROACH`): holding would keep it near, going on takes it away. Whether it will hold."""
        f = self.params.faults
        traj = self._active
        if f.yield_s <= 0.0 or traj is None or not self._may_yield():
            return False
        m = self.model
        unseen = min(max(unseen_s, 0.0) * max(m.speed.drive, m.speed.fly), YIELD_UNSEEN_MAX)
        reach_xy = 2.0 * m.radius + f.guard_factor * m.margin + unseen
        reach_z = m.height + f.guard_factor * m.margin + unseen
        est = self.estimator.estimate(now)
        rel = self._rel(now)
        # where it is, then its plan from a little behind (it may lag its reference) to `yield_s` ahead
        places = [(-1.0, (est.x, est.y, est.z))] + [
            (k * YIELD_STEP_S, traj.plan_position(min(max(rel + k * YIELD_STEP_S, 0.0), traj.end_time)))
            for k in range(-int(YIELD_BEHIND_S / YIELD_STEP_S), int(f.yield_s / YIELD_STEP_S) + 1)]

        def gap(x: float, y: float, z: float) -> float:  # < 0: within reach (the column below, descending)
            return max(math.hypot(x - pos[0], y - pos[1]) - reach_xy,
                       (z - pos[2] if descending else abs(z - pos[2])) - reach_z)

        now_gap = gap(est.x, est.y, est.z)
        if not any(gap(*p) < now_gap - YIELD_APPROACH for ahead, p in places if ahead >= 0.0):
            return False  # its plan keeps its distance or leaves: holding would keep it near
        for ahead, (x, y, z) in places:
            if gap(x, y, z) < 0.0:
                where = "where it is" if ahead < -YIELD_BEHIND_S else f"where its plan goes in {max(ahead, 0.0):.1f} s"
                what = "coming down from" if descending else "held at"
                self._yield = f"yields to {vid}, {what} ({pos[0]:.2f}, {pos[1]:.2f}, {pos[2]:.2f}), {where}"
                return True
        return False

    def _may_yield(self) -> bool:
        """Whether the vehicle follows its plan and may be held for another's sake (`yield_to`,
        `stop_short`): a fault landing, an emergency descent or an aborted mission goes on."""
        return (self.params.faults.guard and self._active is not None and self.t0 is not None and not self.held
                and not self._yield and not self._fault_landing and not self._abort
                and self.machine.mode not in PAST_PLAN)

    def _landing_flight(self) -> bool:
        """Whether the vehicle is on a fault landing's level flight to above its node (its
        descent not begun), at its last tick."""
        step, traj = self.landing_step, self._active
        return (step is not None and traj is not None and self._seen is not None and len(traj.steps) > 2
                and self.machine.mode == Mode.LANDING and self._rel(self._seen[0]) < traj.steps[-2].t)

    def motion(self) -> tuple[float, float, float, float, float, float] | None:
        """The last tick's estimated and planned velocities (vx, vy, vz of each, flat) while the
        vehicle moves on its plan (driving, taking off, flying, landing) or flies to the node of a
        fault landing, for the proximity stop (`services/executor/proximity.py`); None otherwise."""
        if self._seen is None or self.machine.mode not in MOVING or not (self._may_yield() or self._landing_flight()):
            return None
        _, est, ref = self._seen
        if est.stale or ref is None:
            return None
        return est.vx, est.vy, est.vz, ref.vx, ref.vy, ref.vz

    def plan_clock(self, now: float) -> tuple[str, float, float] | None:
        """Its mission, its plan's time at `now` and its clock's pace, while the vehicle follows its
        own plan and may be held (`_may_yield`; not a hold's, a detour's or a landing's reference),
        for the proximity stop's judging on the plans (`services/executor/plan_clearance.py`);
        None otherwise."""
        if self.plan is None or not self._may_yield() or self._active is not self.trajectory or self._hover_ref is not None:
            return None
        return self.plan.mission, self._rel(now), self.pace

    def bend(self, taus: np.ndarray) -> np.ndarray:
        """How far the plan followed at the last tick takes the vehicle in `taus` s beyond the
        straight line at its reference's velocity then (len(taus) x 3, m; at the clock's pace): the
        plan's turns and stops over the proximity stop's look-ahead (`Bodies.closing`), on the
        plan's own way (`Trajectory.plan_positions`, within the smoothing's 5 mm of the reference);
        zero without a plan followed."""
        if self._seen is None or self._seen[2] is None or self._active is None or self._hover_ref is not None:
            return np.zeros((len(taus), 3))
        ref = self._seen[2]
        way = self._active.plan_positions(np.concatenate(((ref.t,), ref.t + self.pace * taus)))
        return way[1:] - way[0] - np.outer(taus, (ref.vx, ref.vy, ref.vz))

    def stop_short(self, why: str) -> bool:
        """The proximity stop: this vehicle heads into another body (`why`), or its mission holds
        it (`MissionAbort.hold`: a replan could not place it); it holds at its next tick, like a
        vehicle the tracking guard holds, for another's sake (reported as `tracking_hold`,
        rejoinable: the mission may bring it back). On a fault
        landing's flight to its node (an abort's, a low battery's, a lost link's), which must go on,
        it hovers where it is instead and chooses its node again (`_pause_landing`). Whether it will."""
        if self._landing_flight():
            self._landing_paused = why
            return True
        if not self._may_yield():
            return False
        self._yield = why
        return True

    def pause(self, why: str, other: str, now: float) -> bool:
        """The proximity pause (`ExecutorService._stop_short`): this vehicle, driving or flying on
        its plan, heads into `other`, which keeps to its plan of the same mission (`why`): it stops
        where it is (at its next tick: hovering there, or its wheels stopped; `back_onto_plan`
        later) and keeps its plan's clock standing (`clock_pace` 0 from now: its executor's clock
        stops in this cycle, the others' as they hear it), so that every vehicle of the mission
        stands where its plan has it at one time, which keeps them apart, until its executor lets
        it go on (`go_on`) or holds it (`stop_short`). Not reported: it stays in the mission, on
        its plan; leaving its plan (a fault landing, an abort, a hold) ends it. A pause for the same
        vehicle within `REPAUSE_S` of going on continues the last one: its time counts from that
        one's start, so that pauses one after another stand the mission no longer than one
        (an 80-vehicle soak's driver went on and paused again for the same car three times in 2
        s). Whether it is paused (not in a take-off or landing, nor when it may not be held:
        `_may_yield`)."""
        if self._paused is not None:  # (paused for its own tracking, it moves: held if it heads into one)
            return self._paused.other != OWN_TRACKING
        if (not self._may_yield() or self.machine.mode not in PAUSABLE or self._hover_ref is not None
                or self._active is not self.trajectory):
            return False
        self._begin_pause(why, other, now, here=True)
        return True

    def _begin_pause(self, why: str, other: str, now: float, here: bool) -> None:
        """Pause (`pause`, `_pause_for_tracking`), continuing the last pause for the same `other`
        if it went on from it within `REPAUSE_S`; `here`: it stops where it is first, else it makes
        straight for its plan's standing place."""
        last, self._last_pause = self._last_pause, None
        since = last[0].since if last is not None and last[0].other == other and now - last[1] < REPAUSE_S else now
        self._paused, self._pause_here = Pause(why, other, since, now), here
        self.clock_pace = 0.0
        self.pauses += 1
        log.warning("%s: pauses, its plan's clock standing: %s", self.vid, why)

    @property
    def paused(self) -> Pause | None:
        """The proximity pause the vehicle is in (`pause`), or None."""
        return self._paused

    def back_onto_plan(self) -> None:
        """Paused (`pause`), it leaves the place where it stopped for the one its plan has it at
        (its clock standing, every other vehicle of the mission has come to its plan's place too)."""
        self._pause_here, self._pause_ref = False, None

    def go_on(self, now: float) -> None:
        """End the pause: the vehicle follows its plan again, and its clock runs as it lets it
        (`_pace_clock`), back to full pace over `RESUME_S`."""
        if self._paused is not None:
            log.warning("%s: goes on after a pause of %.2f s for %s", self.vid, now - self._paused.since,
                        self._paused.other or "its own tracking")
            self._last_pause, self._resumed = (self._paused, now), now
        self._paused = self._pause_ref = None

    def _still_paused(self, now: float, est: Estimate, ref: RefSample | None) -> bool:
        """Whether the vehicle is paused (`pause`) at this tick; a flyer hovers where it was at the
        first tick paused. A pose gone stale ends the pause: the fault's own handling takes over.
        One paused for its own tracking is judged (`_judge_tracking_pause`: held, it is not paused
        and its supervision ends here too)."""
        if self._paused is None:
            return False
        if est.stale or ref is None:
            self._paused = self._pause_ref = None
            return False
        if self._paused.other == OWN_TRACKING:
            return self._judge_tracking_pause(now, est, ref)
        if self._pause_here and self._pause_ref is None and self.machine.airborne:
            self._pause_ref = _still(ref.t, est, est.yaw)
        return True

    def _follow_plan(self, now: float, rel: float, est: Estimate) -> None:
        traj = self._active
        assert traj is not None
        planned = traj.modes[traj.segment(rel)]
        if planned == Mode.DONE and not self.machine.airborne and self._short_of_goal(rel, est):
            self.machine.request(Mode.DRIVING, now, "behind the plan: driving on to the goal")
            return
        if planned == Mode.LANDING:
            if not self.machine.airborne:
                return  # touched down before the plan's landing ended
            if self.machine.mode != Mode.LANDING:
                self._enter_landing(traj, rel)
        self.machine.request(planned, now, "plan")

    def _short_of_goal(self, rel: float, est: Estimate) -> bool:
        """Past the plan's end by less than `finish_s`, near the goal but not at it yet."""
        traj = self._active
        assert traj is not None
        miss = math.dist((est.x, est.y), traj.nodes[-1][:2])
        return (not self._fault_landing and traj is self.trajectory and rel < traj.end_time + self.params.finish_s
                and self.params.arrive_radius <= miss < self.params.finish_radius)

    def _enter_landing(self, traj: Trajectory, rel: float) -> None:
        """Remember where and when the landing that starts now ends."""
        seg = traj.segment(rel)
        end = next((i for i in range(seg, len(traj.steps)) if traj.modes[i + 1] != Mode.LANDING),
                   len(traj.steps) - 1)
        self._landing_end = traj.times[end]
        self._ground_z = traj.nodes[end][2]

    def _begin_safe_landing(self, now: float, rel: float, est: Estimate, reason: str) -> None:
        """Leave the plan for the nearest ground node; a planned landing already under way just
        ends the mission at its touchdown."""
        self._fault_landing = True
        self._landing_reason = reason
        if self.machine.mode == Mode.LANDING:
            log.info("%s: %s while landing: the mission ends at touchdown", self.vid, reason)
            return
        self._choose_landing(now, rel, est)

    def _planned_landing_blocked(self, est: Estimate, ref: RefSample | None) -> bool:
        """Whether a body stands in the column of the planned landing a fault let go on
        (`_begin_safe_landing`): the plan kept it clear, but an abort stops every driver where it
        is, and such a landing came down onto one stopped on its node (an 80-vehicle soak's abort
        had a landing come down 11 cm deep onto a vehicle standing below it). Asked at every tick
        of such a landing: a driver may still roll in."""
        foot = self._column_foot(ref, Mode.LANDING)
        return foot is not None and not clear_spot((est.x, est.y, est.z), foot, self.model, list(self._bodies()))

    def _choose_landing(self, now: float, rel: float, est: Estimate) -> None:
        """The fault landing's path from where the vehicle is, clear of the other bodies
        (`safe_landing_steps`). With nowhere to land that is clear, it hovers where it is and
        chooses again every `LANDING_RETRY_S` (a vehicle below may drive off, another's landing
        choose elsewhere), until its battery's reserve is spent too: then the nearest node, taken
        or not (a controlled landing onto a body rather than a fall)."""
        assert self.trajectory is not None
        here = (est.x, est.y, est.z)
        steps = safe_landing_steps(here, rel, self.trajectory.steps, self.model, self._bodies(), self._ground())
        if steps is None and self.faults.reserve_spent(self.charge_used_ah, now):
            log.warning("%s: its battery's reserve is spent with every node it may land on taken: "
                        "lands on the nearest", self.vid)
            steps = safe_landing_steps(here, rel, self.trajectory.steps, self.model)
        if steps is None:
            if self._landing_retry is None:
                log.warning("%s: %s, with a body below every node it may land on, below itself and below "
                            "every spot beside it: hovers where it is until one is clear", self.vid,
                            self._landing_reason)
            self._hover_to_choose_again(now, rel, est, "nowhere clear to land")
            return
        self._landing_retry = self._hover_ref = self._waiting = None
        self._active = Trajectory(steps, self.params.trajectory, yaw0=est.yaw)
        self._landing_end = steps[-1].t
        self._ground_z = steps[-1].pos[2]
        if self.machine.mode != Mode.LANDING:
            self.machine.request(Mode.LANDING, now, self._landing_reason)

    def _hover_to_choose_again(self, now: float, rel: float, est: Estimate, why: str) -> None:
        """A fault landing hovers where the vehicle is (no node claimed: `landing_step`) and
        chooses its node again in `LANDING_RETRY_S`."""
        self._landing_retry = now + LANDING_RETRY_S
        self._active = self.trajectory
        self.landing_wait = why
        if self.machine.mode != Mode.HOVERING:
            self._hover_ref = self._hover_here(rel, est)
            self.machine.request(Mode.HOVERING, now, f"{self._landing_reason}: {why}")

    def _pause_landing(self, now: float, rel: float, est: Estimate, why: str) -> None:
        """The proximity stop on a fault landing's flight (`stop_short`): the vehicles of an abort
        each fly to their own nearest clear node at once, and one's flight may cross another's (an
        80-vehicle soak's abort: two pairs came into contact in the air, 11 cm deep). It hovers and
        chooses again: a body then in the way of its flight is passed over (`in_way`)."""
        self._landing_paused = None
        log.warning("%s: its %s landing's flight %s: hovers and chooses again", self.vid, self._landing_reason, why)
        self._hover_to_choose_again(now, rel, est, why)

    def landing_wanted_by(self, vid: str, at: tuple[float, float, float]) -> None:
        """Another executor's vehicle `vid` announced a fault landing coming down at `at`. Two fault
        landings of an abort (no replan follows it) that chose one node at the same moment cannot
        have seen each other's choice: the vehicle whose id sorts later gives the node up, unless it
        has begun its descent, and chooses again at its next tick, the other's landing counted."""
        step = self.landing_step
        if step is not None and self._abort and vid < self.vid and in_column(step.pos, at, self.model):
            self._choose_again = True

    # ---- controllers ----------------------------------------------------------------------

    def _control(self, now: float, est: Estimate, ref: RefSample | None, before: Mode) -> Setpoint:
        mode = self.machine.mode
        if mode in AIRBORNE and mode != Mode.EMERGENCY_LANDING and ref is not None:
            if before in GROUNDED:
                self._ground_z = est.z
                self.lqr.reset()
                self.estimator.set_input((0.0, 0.0, 0.0), now)
                return WheelSetpoint(left=0.0, right=0.0)  # wheels off for the takeoff
            if mode == Mode.LANDING and self._touched_down(est, ref):
                self._after_touchdown(now, ref.t, est)
                self.estimator.set_input((0.0, 0.0, 0.0), now)
                return StopSetpoint()
            if onboard.onboard(self.faults.last_telemetry):  # its own controller flies it (onboard.py)
                return onboard.follow(ref, self.reference(now, onboard.ACCEL_LEAD_S), self.estimator, now,
                                      not self.faults.link_lost(now))
            # commands over a lost link do not reach the vehicle: neither learn from them (the
            # integrators wound up and threw it up on reconnection) nor predict with them; on the
            # ground only thrust above its weight moves it (`felt`)
            link = not self.faults.link_lost(now)
            aloft = est.z - self._ground_z > self.params.liftoff_height
            lead = self.params.actuation_s  # it acts then: on the state and reference of then
            ref_then = (self.reference(now, lead) or ref) if lead > 0.0 else ref
            sp = self.lqr.command(self._acting(est), ref_then, integrate=aloft and link)
            if link:
                self.estimator.command(self.lqr.expected_accel, now, aloft, yaw_rate=self.lqr.yaw_rate)
            else:
                self.estimator.set_input((0.0, 0.0, 0.0), now)
            return sp
        if mode == Mode.EMERGENCY_LANDING:
            return self._emergency(now, est)
        if mode == Mode.DRIVING and self._paused is not None and self._pause_here:
            return StopSetpoint()  # (where it is: pure pursuit would drive on to its plan's place)
        if mode == Mode.DRIVING and ref is not None and not est.stale:
            assert self._active is not None
            turn = self._turn_in_wait(est, ref)
            if turn is not None:
                return turn
            goal = self._active.sample(ref.t + self.pursuit.lookahead(ref))
            return self.pursuit.command(est, ref, goal)
        if mode == Mode.PARKED and ref is not None and not est.stale and self._active is not None:
            turn = self._turn_before_driving(est, ref)
            if turn is not None:
                return turn
        return StopSetpoint()

    def _turn_before_driving(self, est: Estimate, ref: RefSample) -> WheelSetpoint | None:
        """Parked with a plan whose drive starts within `PRE_TURN_S`: turn in place to face it
        (parked facing anywhere, or the way it came after a mission, it would otherwise turn on the
        plan's time and fall behind: by up to 9 cm in a 32-vehicle soak, and a 16-vehicle lifelong
        run had 3 vehicles held by the tracking guard in their first drives). At a mission's start
        the turn happens in the start's lead (`MissionTiming.start_lead_s`); after a mission the
        planner allows its time (`replanning.TURN_ALLOWANCE_S`)."""
        heading = self._next_drive_heading(ref.t, ref.t + PRE_TURN_S)
        return None if heading is None else self.pursuit.turn_towards(est, heading)

    def _turn_in_wait(self, est: Estimate, ref: RefSample) -> WheelSetpoint | None:
        """Driving, at a node where the plan waits: turn in place to face the drive that follows
        (the planner budgets the turn at a corner as a wait there: `services/planner/sipp/turns.py`)."""
        traj = self._active
        assert traj is not None
        seg = traj.segment(ref.t)
        if not 0 < seg < len(traj.times) or any(traj.vel[seg - 1]):
            return None  # not in a wait
        node = traj.nodes[seg - 1]
        if math.hypot(est.x - node[0], est.y - node[1]) > self.pursuit.params.hold_radius:
            return None  # not there yet: pure pursuit brings it
        heading = self._next_drive_heading(ref.t, traj.times[seg])
        return None if heading is None else self.pursuit.turn_towards(est, heading)

    def _next_drive_heading(self, t: float, latest: float) -> float | None:
        """The direction of the plan's next move after `t` if it is a drive that starts by `latest`."""
        traj = self._active
        assert traj is not None
        for k in range(max(traj.segment(t) - 1, 0), len(traj.vel)):
            vx, vy, vz = traj.vel[k]
            if math.hypot(vx, vy) > 1e-9:
                if traj.times[k] > latest or traj.modes[k + 1] != Mode.DRIVING:
                    return None
                return math.atan2(vy, vx)
            if vz != 0.0:
                return None  # a take-off or landing comes first
        return None

    def _touched_down(self, est: Estimate, ref: RefSample) -> bool:
        h = self.params.touchdown_height
        return est.z - self._ground_z < h and ref.z - self._ground_z < h

    def _after_touchdown(self, now: float, rel: float, est: Estimate) -> None:
        if self._fault_landing:
            self.machine.request(Mode.DONE, now, "landed after fault")
            return
        traj = self._active
        assert traj is not None
        nxt = traj.modes[traj.segment(max(rel, self._landing_end))]
        if nxt == Mode.DONE and self._short_of_goal(max(rel, self._landing_end), est):
            nxt = Mode.DRIVING  # landed behind its plan, off the goal: drive onto it
        self.machine.request(Mode.DRIVING if nxt == Mode.LANDING else nxt, now, "touchdown")

    def _emergency(self, now: float, est: Estimate) -> Setpoint:
        """Descent on the dead-reckoned state, its horizontal speed braked, then level (the
        estimator integrates the accelerations commanded here; a level descent drifted 1.6-2 m from
        cruise speed on a slow loop with poses coming and going); the thrust allows for the thrust
        model's error the estimator learned (`PoseEstimator.lift_error`; within what a thrust model
        can be wrong by, `FaultParams.descent_bias_max`). Motors off
        after the predicted descent time again plus a margin (see `FaultParams`). With poses back
        the flight controller lands it where it is (`LandInPlace`): the prediction assumed every
        command arrived, which a lost router or radio makes false (the gateway may have been
        landing it its own way), and a stalled loop's wound-up integrators made it climb blind.
        Where it is, or over the foot of its column (`_back_over`), unless another body is in the
        column there: then beside it (`_beside_a_body`)."""
        faults, descent = self.params.faults, self._descent
        assert descent is not None
        on_board = onboard.onboard(self.faults.last_telemetry)
        if not est.stale and not on_board:  # (a blind prediction of the touchdown is void: it is here)
            descent.cut = None
            over, not_before = None, now
            if descent.landing.anchor is None:  # (where it comes down is chosen as its landing begins)
                over = self._back_over(est)
                if (beside := self._beside_a_body(est, over)) is not None:
                    over = beside  # level first, then down: its way there is clear, its descent near a body may not be
                    descent.aside = (*beside, self._ground_z)
                    not_before = now + ASIDE_HOLD_S + math.hypot(beside[0] - est.x, beside[1] - est.y) / self.model.speed.fly
            sp = descent.landing.step(now, est, ground=self._ground_z, not_before=not_before, over=over)
            if sp is None:
                self._descent_complete(now, est)
                return StopSetpoint()
            return sp
        if descent.landing.anchor is not None:  # blind again: predict afresh from here
            descent.landing.release()
            descent.start = now
        if descent.cut is None and est.z <= self._ground_z:  # predicted touchdown
            descent.cut = now + faults.descent_slack * (now - descent.start) + faults.descent_margin_s
        if descent.cut is not None and now >= descent.cut and (est.stale or abs(est.vz) < REST_SPEED):
            self._descent_complete(now, est)
            return StopSetpoint()
        if on_board:
            return onboard.descent(est, faults.descent_accel_cmd(est.vz), self.estimator, faults, now)
        est = self._acting(est)
        accel = faults.descent_accel_cmd(est.vz)
        ax, ay = faults.descent_brake(est.vx, est.vy)
        c, s = math.cos(est.yaw), math.sin(est.yaw)
        pitch, roll = (ax * c + ay * s) / G, (ax * s - ay * c) / G  # (v'x = g pitch, v'y = -g roll, yawed frame)
        d = self.lqr.model.drag_rate  # the thrust also makes up for the drag of the descent
        k = max(self.estimator.lift_error, 0.0)  # the thrust model's error learned: (1 + k)(g + bias + accel) = g + accel
        bias = min(max((G + accel) / (1.0 + k) - G - accel, -faults.descent_bias_max), faults.descent_bias_max)
        self.estimator.command((ax - d * est.vx, ay - d * est.vy, accel + bias), now, aloft=True, learn=False,
                               yaw_rate=0.0)
        thrust = self.model.mass * (G + bias + accel + d * est.vz) / (math.cos(roll) * math.cos(pitch))
        return to_flight_setpoint(roll, pitch, 0.0, thrust_command(thrust))

    def _acting(self, est: Estimate) -> Estimate:
        """The state predicted to when a command given now acts (`ACTUATION_S`): `est`, the
        estimate at `now`, carried on (itself with no delay to lead)."""
        lead = self.params.actuation_s
        return self.estimator.ahead(est, lead) if lead > 0.0 else est

    def _column_foot(self, ref: RefSample | None, mode: Mode) -> tuple[float, float] | None:
        """Where (x, y) on the ground the take-off or landing (`mode`) it is in stands: of its
        plan's last take-off (landing) that has begun by `ref`'s time, the first (last) node. (A
        take-off edge may lean: town's go 5 cm sideways as they climb 0.4 m, and a take-back passes
        the foot, not the point beneath where the poses went; a late take-off's reference may be
        past it already.) The reference's x, y if the plan has none."""
        traj = self._active
        if ref is None or traj is None:
            return None
        j = min(traj.segment(ref.t), len(traj.nodes) - 1)
        while j > 0 and traj.modes[j] != mode:
            j -= 1
        if j == 0:
            return (ref.x, ref.y)
        x, y, _ = traj.nodes[j - 1] if mode == Mode.TAKING_OFF else traj.nodes[j]
        return (x, y)

    def _emergency_descent(self, now: float, column: tuple[float, float] | None = None,
                           beneath: tuple[float, float] | None = None) -> EmergencyDescent:
        p = self.params
        return EmergencyDescent(now, LandInPlace(self.lqr, self.estimator, p.faults.descent_speed, p.touchdown_height,
                                                 p.faults.rest_s, p.liftoff_height, Mode.EMERGENCY_LANDING),
                                column=column, beneath=beneath)

    def _back_over(self, est: Estimate) -> tuple[float, float] | None:
        """Where an emergency descent with its poses back lands: over the foot of the take-off or
        landing it lost them in, when it is within the guard's reach of where its reference was
        then (its blind descent drifts, and a take-off may lean: it comes down where a take-back
        passes, `_descent_complete`; in a fleet flight one that landed where its poses came back
        had every take-back refused, its shifted path's reference passing farther than the
        guard's reach from it), else where it is."""
        descent = self._descent
        if descent is None or descent.column is None or descent.beneath is None:
            return None
        x, y = descent.beneath
        if math.hypot(est.x - x, est.y - y) > self.params.faults.guard_factor * self.model.margin:
            return None
        return descent.column

    def _beside_a_body(self, est: Estimate, over: tuple[float, float] | None) -> tuple[float, float] | None:
        """Where an emergency descent with its poses back comes down if another body is in the
        column it would come down in (`over`: the foot of its take-off's or landing's column,
        `_back_over`; None: straight down from where it is): the nearest clear spot beside it under
        its plan's flights, as a fault landing chooses (`spot_beside`); None: there after all (no
        body in that column, or no spot clear). (An 80-vehicle soak's motion capture stalled, every
        vehicle held in the air came down where it was, and four landed on vehicles parked below,
        0.5-6 cm deep.)"""
        bodies = list(self._bodies())
        here = (est.x, est.y, est.z)
        if self.trajectory is None or clear_spot(here, over or (est.x, est.y), self.model, bodies):
            return None
        return spot_beside(here, self.trajectory.steps, self.model, bodies, self._ground(), self._ground_z)

    def _descent_complete(self, now: float, est: Estimate) -> None:
        """Motors off after an emergency descent. One that lost its poses in a take-off or landing
        of its plan and is back on the ground, seen, in that column (within the guard's reach of
        it) is held there like a vehicle a fault that cleared stopped on the ground (`rejoinable`):
        the mission may bring it back (`services/mission/rejoin.py`: its path shifted so that the
        take-off or the drive after the landing starts from here; a 32-vehicle soak's stall of
        0.3-0.4 s in the motion capture took every vehicle then taking off out of its mission).
        Any other is done, and so is one held so `BLIND_RETURNS` times already this mission."""
        column = None if self._descent is None else self._descent.column
        reach = self.params.faults.guard_factor * self.model.margin
        if (column is None or est.stale or self._abort or self._active is None or self.t0 is None
                or self._blind_returns >= BLIND_RETURNS
                or self.faults.link_lost(now) or self.faults.low_battery(self.charge_used_ah, now)
                or math.hypot(est.x - column[0], est.y - column[1]) > reach):
            self.machine.request(Mode.DONE, now, "emergency descent complete")
            return
        self.held, self.rejoinable = "landed blind in its take-off or landing (pose stale in the air)", True
        self.holds += 1
        self._blind_returns += 1
        self.machine.request(Mode.HOLDING, now, "emergency descent complete, seen where it took off or lands")
        log.warning("%s: held where it came down: %s", self.vid, self.held)

    # ---- accounting and state -------------------------------------------------------------

    def _power(self, ref: RefSample | None) -> float:
        """Power the mode draws (Table II), for the eq. 4-5 charge estimate."""
        mode = self.machine.mode
        if mode in AIRBORNE:
            return self.model.power.fly
        if mode == Mode.DRIVING and ref is not None and abs(ref.vx) + abs(ref.vy) > 1e-6:
            return self.model.power.drive
        return self.model.power.idle

    @property
    def ticked(self) -> bool:
        """Whether it has ticked (and has a `state`)."""
        return self._seen is not None

    def state(self) -> VehicleState:
        """The vehicle's state as the last `tick` saw it (its estimate, reference and mode)."""
        if self._seen is None:
            raise RuntimeError(f"{self.vid}: no state before the first tick")
        now, est, ref = self._seen
        mode = self.machine.mode  # held on the ground or coming down blind, it follows no reference:
        err = 0.0  # its plan's runs on without it
        if ref is not None and not est.stale and mode != Mode.EMERGENCY_LANDING and not (mode == Mode.HOLDING and self.held):
            err = math.dist((est.x, est.y, est.z), (ref.x, ref.y, ref.z))
        traj = self.trajectory
        arrived = False
        if traj is not None and self.machine.mode == Mode.DONE and not est.stale:
            arrived = math.dist((est.x, est.y, est.z), traj.nodes[-1]) < self.params.arrive_radius
        return VehicleState(
            vid=self.vid, t=now, owner=self.owner, mode=str(self.machine.mode),
            x=est.x, y=est.y, z=est.z, yaw=est.yaw, vx=est.vx, vy=est.vy, vz=est.vz,
            pose_ok=not est.stale, mission=self.plan.mission if self.plan else "",
            step=traj.segment(self._rel(now)) if traj is not None and self.t0 is not None else 0,
            steps=len(traj.steps) if traj is not None else 0,
            tracking_error=err, charge_used_ah=self.charge_used_ah, arrived=arrived,
            landing=landing.pos if (landing := self.landing_step) is not None else None,
            held=self.held or "", rejoinable=self.rejoinable, delay=self.delay)
