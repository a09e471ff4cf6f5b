"""Where a fault landing comes down in a fleet: the executor tells its controllers where the other
vehicles are and where other executors' fault landings come down (their `VehicleState.landing`,
over the bus), and `safe_landing_steps` passes over those nodes (docs/control.md, faults)."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable

import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.messages import Pose, Telemetry, VehicleEvent, VehicleState, VehicleStates
from common.bus.pubsub import Publisher, subscribe
from common.bus.session import ZenohConfig
from common.domain.mapfile import MapSpec, NoFlyZone, Obstacle, RoadNode, Roads
from common.domain.vehicle_model import VehicleModel
from common.flight.modes import Mode
from services.executor.faults import (
    ASIDE,
    ASIDE_REACH,
    STRAIGHT_DOWN,
    safe_landing_steps,
    spots_under_flights,
)
from services.executor.service import ExecutorService
from services.executor.vehicle_controller import VehicleController
from services.sim.crazyflie.physics import SimFlyingCar
from tests.support.closed_loop import Mocap, MocapNoise, Record, plan_for, reference_steps, run

KEYS = Keys("landing")
MODEL = VehicleModel()
STEPS = reference_steps(MODEL)
PADS = {s.node: s.pos for s in STEPS if s.node in ("l1", "l2")}
COLUMN = 2.0 * MODEL.radius + MODEL.margin
"""The column a fault landing comes down through (`in_column`)."""


def either_side(x: float, y: float, z: float) -> list[tuple[float, float, float]]:
    """Two vehicles hovering, held, 15 cm before and after (x, y, z) on the flight from l1 to l2:
    the flight to every spot beside it under that flight passes one of them, or the spot is in one
    of their columns (`safe_landing_steps`)."""
    return [(x - 0.15, y, z), (x + 0.15, y, z)]


def state(vid: str, owner: str, landing: tuple[float, float, float] | None) -> VehicleState:
    return VehicleState(vid=vid, t=0.0, owner=owner, mode="landing", x=2.0, y=0.45, z=0.5, yaw=0.0,
                        landing=landing)


@pytest.mark.timeout(30)
def test_another_executors_fault_landing_is_heard_and_its_node_passed_over(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    above_l2 = (PADS["l2"][0], PADS["l2"][1], 0.5)

    def target(svc: ExecutorService) -> str:
        return safe_landing_steps(above_l2, 0.0, STEPS, MODEL, svc._bodies_besides("cf1"))[-1].node

    async def scenario() -> list[str]:
        svc = ExecutorService("e1", ZenohConfig.client(zenoh_router), KEYS)
        run = asyncio.create_task(svc.run())
        session = zsession()
        theirs = Publisher(session, KEYS.executor_states("e2"), VehicleStates)
        ours = Publisher(session, KEYS.executor_states("e1"), VehicleStates)
        chosen = []
        try:
            for landing in (None, PADS["l2"], None):
                theirs.put(VehicleStates(owner="e2", t=0.0, states=[state("cf2", "e2", landing)]))
                for _ in range(100):  # until the executor has heard it
                    await asyncio.sleep(0.02)
                    if ("cf2" in svc._landings) == (landing is not None):
                        break
                chosen.append(target(svc))
            ours.put(VehicleStates(owner="e1", t=0.0, states=[state("cf1", "e1", PADS["l2"])]))  # its own: not another's
            await asyncio.sleep(0.3)
            chosen.append(target(svc))
        finally:
            svc.stop()
            assert await run == 0
        return chosen

    # nothing there: the nearest (l2); cf2 of e2 coming down on l2: l1; cf2 landed elsewhere: l2
    assert asyncio.run(scenario()) == ["l2", "l1", "l2", "l2"]


@pytest.mark.parametrize("other, node", [("cf1", "l1"), ("cf3", "l2")])
def test_two_fault_landings_of_an_abort_that_chose_one_node_part(other: str, node: str) -> None:
    """cf2 and `other` (another executor's) aborted at once as cf2 flew towards its landing node l2
    (0.3 m short of it) and both chose l2; 50 ms later cf2 hears `other`'s landing there (its state).
    The one whose id sorts first keeps the node: cf2 gives it up to cf1 and lands on l1, the node it
    took off from; it keeps it from cf3."""
    t0 = 0.5
    above = t0 + next(s.t for s in STEPS if s.node == "a2")
    abort, heard = above - 1.0, above - 0.95
    sim = SimFlyingCar("cf2", MODEL, pos=STEPS[0].pos, yaw=0.0)
    announced: list[tuple[float, float, float]] = []
    ctrl = VehicleController("cf2", MODEL, owner="e1", bodies=lambda: announced)
    ctrl.on_pose(Pose(vid="cf2", t=0.0, x=sim.x, y=sim.y, z=sim.z, yaw=sim.yaw))
    ctrl.load(plan_for("cf2", STEPS, MODEL, t0=t0))

    def hook(now: float) -> None:
        if now >= abort and not ctrl._abort:
            ctrl.abort("abort")
        if now >= heard and not announced:  # the executor records it, then tells its controllers
            announced.append(PADS["l2"])
            ctrl.landing_wanted_by(other, PADS["l2"])

    records = run(ctrl, sim, above + 11.0, Mocap(), on_tick=hook)
    assert [tr.reason for tr in ctrl.machine.history][-2:] == ["abort", "landed after fault"]
    assert math.dist((sim.x, sim.y, sim.z), PADS[node]) < 0.03, (node, sim.x, sim.y, sim.z)
    if node == "l1":  # never came down near the node it gave up
        low = [r for r in records if r.t > abort and r.truth.z < 0.4]
        assert low and min(math.dist((r.truth.x, r.truth.y), PADS["l2"][:2]) for r in low) > 0.5


def test_with_every_node_taken_it_lands_straight_down_if_clear_below_else_beside_it_else_nowhere() -> None:
    above = (1.2, 0.45, 0.5)  # over the flight between l1 and l2
    on_l1, on_l2 = (*PADS["l1"][:2], 0.0), (*PADS["l2"][:2], 0.0)
    assert safe_landing_steps(above, 0.0, STEPS, MODEL, [on_l2])[-1].node == "l1"
    down = safe_landing_steps(above, 0.0, STEPS, MODEL, [on_l1, on_l2])
    assert down is not None and down[-1].node == STRAIGHT_DOWN and down[-1].pos == (1.2, 0.45, 0.0)
    assert safe_landing_steps(above, 0.0, STEPS, MODEL, [(1.2, 0.45, 0.6)])[-1].node == "l1"  # above it: no matter
    # a body parked 5 cm on: beside it, the nearest spot under its flight whose column is clear of that
    # body (two radii and a margin, 12 cm): 10 cm back along the flight
    parked = (1.25, 0.45, 0.0)
    aside = safe_landing_steps(above, 0.0, STEPS, MODEL, [on_l1, on_l2, parked])
    assert aside is not None and aside[-1].node == ASIDE
    assert aside[-1].pos == pytest.approx((1.10, 0.45, 0.0)) and math.dist(aside[-1].pos, parked) >= COLUMN
    assert [s.edge for s in aside] == ["", "fly", "land"] and aside[1].pos == pytest.approx((1.10, 0.45, 0.5))
    # one hovering, held, on its level 15 cm back (the flight there would pass it): past the parked one
    back = (1.05, 0.45, 0.5)
    aside = safe_landing_steps(above, 0.0, STEPS, MODEL, [on_l1, on_l2, parked, back])
    assert aside is not None and aside[-1].node == ASIDE and aside[-1].pos == pytest.approx((1.40, 0.45, 0.0))
    # and one 15 cm on: nowhere
    assert safe_landing_steps(above, 0.0, STEPS, MODEL, [on_l1, on_l2, parked, back, (1.35, 0.45, 0.5)]) is None


def test_the_spots_beside_it_are_under_its_plans_flights_only() -> None:
    """Off the flight (15 cm to its side, where no flight of the plan passes: under it may be a
    no-fly zone), the spots it comes down on beside itself are still on the flight's line, the
    nearest first; spots farther than `ASIDE_REACH` are not tried."""
    beside = (1.2, 0.60, 0.5)
    spots = spots_under_flights(beside, STEPS)
    assert spots and all(y == pytest.approx(0.45) for _, y in spots)
    assert all(math.dist(beside[:2], s) <= ASIDE_REACH for s in spots)
    assert spots[0] == pytest.approx((1.2, 0.45))
    dists = [math.dist(beside[:2], s) for s in spots]
    assert dists == sorted(dists)
    assert spots_under_flights((1.2, 1.2, 0.5), STEPS) == []  # 0.75 m from any flight
    on_l1, on_l2 = (*PADS["l1"][:2], 0.0), (*PADS["l2"][:2], 0.0)
    aside = safe_landing_steps(beside, 0.0, STEPS, MODEL, [on_l1, on_l2, (1.2, 0.62, 0.0)])
    assert aside is not None and aside[-1].node == ASIDE and aside[-1].pos == pytest.approx((1.2, 0.45, 0.0))


def test_a_landing_off_the_graph_keeps_out_of_the_maps_obstacles_and_no_fly_zones() -> None:
    """Every node taken, over a building under the flight (x 1.12-1.35: a map's obstacle, which the
    planner keeps clear of at the flight's height only): not straight down onto its roof, nor
    beside it within a radius of it, but the nearest spot past it, 15 cm back; a no-fly zone
    there too: 25 cm on. Without the map the same call comes straight down."""
    above = (1.2, 0.45, 0.5)
    taken = [(*PADS["l1"][:2], 0.0), (*PADS["l2"][:2], 0.0)]
    roads = Roads(nodes={"r": RoadNode(0.0, 0.0)})
    building = Obstacle(name="building", min=(1.12, 0.3, 0.0), max=(1.35, 0.6, 0.15))
    town = MapSpec(name="t", roads=roads, obstacles=[building])
    assert safe_landing_steps(above, 0.0, STEPS, MODEL, taken)[-1].node == STRAIGHT_DOWN
    aside = safe_landing_steps(above, 0.0, STEPS, MODEL, taken, town)
    assert aside is not None and aside[-1].node == ASIDE and aside[-1].pos == pytest.approx((1.05, 0.45, 0.0))
    zone = NoFlyZone(name="school", polygon=[(0.9, 0.3), (1.1, 0.3), (1.1, 0.6), (0.9, 0.6)])
    walled = MapSpec(name="t", roads=roads, obstacles=[building], no_fly=[zone])
    aside = safe_landing_steps(above, 0.0, STEPS, MODEL, taken, walled)
    assert aside is not None and aside[-1].pos == pytest.approx((1.45, 0.45, 0.0))


@pytest.mark.timeout(30)
def test_the_executor_reads_its_plans_map_off_its_loop(zenoh_router: str, caplog: pytest.LogCaptureFixture) -> None:
    """What its fault landings off the graph keep out of: the plan's map, read on a thread; one
    that cannot be read here is None, with a warning."""
    svc = ExecutorService("e1", ZenohConfig.client(zenoh_router), KEYS)
    town, nowhere = svc._map("town"), svc._map("no-such-map")
    for _ in range(100):
        if town() is not None and "no-such-map" in caplog.text:
            break
        time.sleep(0.02)
    spec = town()
    assert spec is not None and [o.name for o in spec.obstacles] == ["building"]
    assert nowhere() is None and "a fault landing off the graph will not know its no-fly zones" in caplog.text


def hovering_abort(bodies: Callable[[float], list[tuple[float, float, float]]], spend_reserve_at: float = math.inf
                   ) -> tuple[VehicleController, SimFlyingCar, list, float]:
    """cf2 held by the proximity stop 1 s into its flight from l1 to l2 (hovering about 0.3 m past
    l1), then its mission aborted: the records, and when the abort came."""
    t0 = 0.5
    held = t0 + next(s.t for s in STEPS if s.node == "a1") + 1.0
    abort = held + 2.0
    sim = SimFlyingCar("cf2", MODEL, pos=STEPS[0].pos, yaw=0.0)
    now = [0.0]
    ctrl = VehicleController("cf2", MODEL, owner="e1", bodies=lambda: bodies(now[0] - abort))
    ctrl.on_pose(Pose(vid="cf2", t=0.0, x=sim.x, y=sim.y, z=sim.z, yaw=sim.yaw))
    ctrl.load(plan_for("cf2", STEPS, MODEL, t0=t0))

    def hook(t: float) -> None:
        now[0] = t
        if t >= held and not ctrl.held:
            ctrl.stop_short("a test's")
        if t >= abort and not ctrl._abort:
            ctrl.abort("abort")
        if t >= abort + spend_reserve_at:
            ctrl.charge_used_ah = max(ctrl.charge_used_ah, MODEL.capacity_ah)

    return ctrl, sim, run(ctrl, sim, abort + 12.0, Mocap(), on_tick=hook), abort


def test_a_fault_landing_with_nowhere_clear_hovers_until_the_vehicle_below_drives_off() -> None:
    """The abort finds vehicles on both nodes of cf2's plan, one parked right below it, which
    drives off 3 s later, and one hovering on either side of it: cf2 hovers where it is until then
    and comes straight down after it (it used to land on the nearest node all the same: onto the
    vehicle there)."""
    nodes = [(*PADS["l1"][:2], 0.0), (*PADS["l2"][:2], 0.0)]
    below: list[tuple[float, float, float]] = []
    beside: list[tuple[float, float, float]] = []

    def bodies(since_abort: float) -> list[tuple[float, float, float]]:
        return nodes + beside + (below if since_abort < 3.0 else [])

    ctrl, sim, records, abort = hovering_abort(bodies)
    at_abort = next(r.truth for r in records if r.t >= abort)
    below.append((at_abort.x, at_abort.y, 0.0))
    beside += either_side(at_abort.x, at_abort.y, at_abort.z)
    ctrl, sim, records, abort = hovering_abort(bodies)  # again, the vehicle below there from the start
    waiting = [r for r in records if abort + 0.1 <= r.t < abort + 3.0]
    assert all(r.mode == Mode.HOVERING and r.truth.z > 0.4 for r in waiting)
    *_, hold, landing, landed = ctrl.machine.history  # (held already: it hovers on)
    assert (hold.reason, landing.reason, landed.reason) == ("a test's", "abort", "landed after fault")
    assert abort + 3.0 <= landing.t < abort + 3.0 + 0.6  # chosen again every 0.5 s
    assert math.dist((sim.x, sim.y), below[0][:2]) < 0.05 and sim.z < 0.01
    assert ctrl.landing_step is not None and ctrl.landing_step.node == STRAIGHT_DOWN


def test_a_fault_landing_flies_round_no_body_hovering_in_its_way() -> None:
    """cf2 hovers 0.3 m past l1 when its mission aborts, with another vehicle hovering, held, between
    it and l1 at its height: it lands on l2 instead, 1.2 m on, and never comes near the other (it
    used to fly level to l1, the nearest, through it: four such contacts in an 80-vehicle soak's
    abort). A body behind it, which the flight to l1 only leaves, is no reason to go elsewhere."""
    between = (0.80, 0.45, 0.50)
    ctrl, sim, records, abort = hovering_abort(lambda _s: [between])
    assert math.dist((sim.x, sim.y, sim.z), PADS["l2"]) < 0.03
    after = [r.truth for r in records if r.t >= abort]
    assert min(math.dist((r.x, r.y, r.z), between) for r in after) > 2.0 * MODEL.body()[0] + 0.02
    behind = (1.10, 0.45, 0.50)
    ctrl, sim, records, abort = hovering_abort(lambda _s: [behind])
    assert math.dist((sim.x, sim.y, sim.z), PADS["l1"]) < 0.03
    boxed = [between, behind]  # with one on either side it comes straight down, if clear below
    assert safe_landing_steps((0.95, 0.45, 0.5), 0.0, STEPS, MODEL, boxed)[-1].node == STRAIGHT_DOWN
    assert safe_landing_steps((0.95, 0.45, 0.5), 0.0, STEPS, MODEL, [*boxed, (0.95, 0.45, 0.0)]) is None
    assert safe_landing_steps((0.95, 0.45, 0.5), 0.0, STEPS, MODEL, [(0.80, 0.45, 0.3)])[-1].node == "l1"  # beneath its level


def test_a_fault_landing_with_its_reserve_spent_takes_the_nearest_node_all_the_same() -> None:
    nodes = [(*PADS["l1"][:2], 0.0), (*PADS["l2"][:2], 0.0)]
    ctrl, sim, records, abort = hovering_abort(lambda _s: nodes + [(0.95, 0.45, 0.0), *either_side(0.95, 0.45, 0.5)],
                                               spend_reserve_at=2.0)
    assert all(r.truth.z > 0.4 for r in records if abort + 0.1 <= r.t < abort + 2.0)
    assert math.dist((sim.x, sim.y, sim.z), PADS["l1"]) < 0.03


def flown_with_reports(ctrl: VehicleController, sim: SimFlyingCar, until: float, mocap: Mocap,
                       hook: Callable[[float], None], zenoh_router: str, zsession: Callable[..., zenoh.Session],
                       **run_kw) -> tuple[list[Record], list[VehicleEvent]]:
    """`run` the closed loop with executor e1 reporting its vehicle's modes (`_report_mode`) every
    tick after `hook`; its records and the events heard on the bus."""
    heard: list[VehicleEvent] = []

    async def scenario() -> list[Record]:
        svc = ExecutorService("e1", ZenohConfig.client(zenoh_router), KEYS)
        run_svc = asyncio.create_task(svc.run())
        events = subscribe(zsession(), KEYS.vehicle(ctrl.vid, "event"), VehicleEvent,
                           lambda event, _key: heard.append(event))
        await asyncio.sleep(0.5)

        def tick(now: float) -> None:
            hook(now)
            if ctrl._seen is not None:
                svc._report_mode(ctrl.vid, ctrl, now)

        try:
            records = run(ctrl, sim, until, mocap, on_tick=tick, **run_kw)
            await asyncio.sleep(0.5)
        finally:
            events.close()
            svc.stop()
            assert await run_svc == 0
        return records

    return asyncio.run(scenario()), heard


@pytest.mark.timeout(60)
@pytest.mark.parametrize("boxed_in", [True, False])
def test_a_lost_links_landing_with_nowhere_clear_is_reported_hovering_then_straight_down_or_beside(
        boxed_in: bool, zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    """The executor's events for a fault landing that waits or goes beside the vehicle (what the
    mission plans the others around): cf2's link is lost in flight with bodies on both nodes of its
    plan and one right below it. Heard on the bus, each marked as the
    executor's report of what it does (`acted`: the mission tells them from a gateway's `link_lost`,
    which it leaves to the executor), with where it comes down (`at`). With a vehicle hovering on
    either side of it (and the one below driving off 2 s later): "link_lost from flying: hovering here, nowhere clear to land", then
    "link_lost from hovering: landing straight down" naming the node `STRAIGHT_DOWN` (a descent for
    the replan). Without: at once "link_lost from flying: landing beside it at (x, y)", node `ASIDE`,
    down onto a spot under its flight, clear of the body below (ground truth)."""
    nodes = [(*PADS["l1"][:2], 0.0), (*PADS["l2"][:2], 0.0)]
    below: list[tuple[float, float, float]] = []
    t0 = 0.5
    lost = t0 + next(s.t for s in STEPS if s.node == "a1") + 1.0
    sim = SimFlyingCar("cf2", MODEL, pos=STEPS[0].pos, yaw=0.0)
    lowest: list[float] = []  # how near the body below cf2 came, horizontally, within 0.45 m of the ground
    ctrl = VehicleController("cf2", MODEL, owner="e1", bodies=lambda: nodes + below)
    ctrl.on_pose(Pose(vid="cf2", t=0.0, x=sim.x, y=sim.y, z=sim.z, yaw=sim.yaw))
    ctrl.load(plan_for("cf2", STEPS, MODEL, t0=t0))

    def hook(now: float) -> None:
        link_ok = now < lost
        if round(now / 0.01) % 10 == 0:
            ctrl.on_telemetry(Telemetry(vid="cf2", t=now, gateway="sim", vbat=4.0, link_quality=1.0, sent=0,
                                        dropped=0, cmd_rate_hz=100.0, link_ok=link_ok), now)
        if now >= lost and not below and not ctrl._fault_landing:
            below.append((sim.x, sim.y, 0.0))
            if boxed_in:
                nodes.extend(either_side(sim.x, sim.y, sim.z))
        if below and sim.z < 0.45:
            lowest.append(math.dist((sim.x, sim.y), below[0][:2]))
        if boxed_in and below and now >= lost + 2.0:
            below.clear()

    _, events = flown_with_reports(ctrl, sim, lost + 6.0, Mocap(), hook, zenoh_router, zsession, telemetry_every=0)
    heard = [(e.kind, f"{e.detail} ({e.node})", e.acted) for e in events]
    where = [e.at for e in events]
    assert ctrl.mode == Mode.DONE and sim.z < 0.01
    if boxed_in:
        assert heard == [("link_lost", "from flying: hovering here, nowhere clear to land ()", True),
                         ("link_lost", f"from hovering: landing straight down ({STRAIGHT_DOWN})", True)], heard
        assert where == [None, None]  # (straight down from where it is: no spot to name)
        return
    assert len(heard) == 1 and heard[0][0] == "link_lost" and heard[0][2], heard
    assert heard[0][1].startswith("from flying: landing beside it at (") and heard[0][1].endswith(f") ({ASIDE})")
    spot = where[0]
    assert spot is not None and spot[1] == pytest.approx(0.45) and spot[2] == 0.0  # under its flight
    assert math.dist((sim.x, sim.y), spot[:2]) < 0.03
    assert lowest and min(lowest) >= COLUMN - 0.02  # never came down onto the body below


@pytest.mark.timeout(60)
@pytest.mark.parametrize("where", ["flight, parked below", "flight, nothing below", "take-off, parked on its foot"],
                         ids=["parked_below", "nothing_below", "parked_on_its_take_off_foot"])
def test_an_emergency_descent_with_its_poses_back_comes_down_beside_a_body_in_its_column_and_says_where(
        where: str, zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    """An 80-vehicle soak's motion capture stalled; every vehicle held in the air came down in an
    emergency landing where it was, and four onto vehicles parked below (0.5-6 cm deep). Here cf2
    loses its poses for 0.6 s in its flight from l1 to l2 (stale after 0.4 s: an emergency
    landing); as they come back a vehicle is parked right below it. It holds its height, moves to
    the nearest clear spot under its flight and comes down there, clear of the parked one's column
    (ground truth), and its executor says where (an "emergency_landing" event naming `ASIDE` and
    the spot, after the one of the landing itself: the mission plans the others around it). With
    nothing below, it comes down where it is, as before, and says no more. Lost near the top of
    its take-off from l1, it would come down over l1 (`_back_over`); with a vehicle parked on l1
    by then, it comes down beside it too. (With the shipped maps' margin: the take-off's column is
    within the guard's reach of it, `_back_over`.)"""
    t0, model = 0.5, VehicleModel(margin=0.03)
    width = 2.0 * model.radius + model.margin
    if where.startswith("take-off"):
        top = next(k for k, s in enumerate(STEPS) if s.edge == "takeoff")
        lost = t0 + STEPS[top - 1].t + 0.8 * (STEPS[top].t - STEPS[top - 1].t)
        column = STEPS[top - 1].pos[:2]
    else:
        lost, column = t0 + next(s.t for s in STEPS if s.node == "a1") + 1.0, None
    sim = SimFlyingCar("cf2", model, pos=STEPS[0].pos, yaw=0.0)
    below: list[tuple[float, float, float]] = []
    ctrl = VehicleController("cf2", model, owner="e1", bodies=lambda: below)
    ctrl.load(plan_for("cf2", STEPS, model, t0=t0))
    at: list[tuple[float, float]] = []

    def hook(now: float) -> None:
        if now >= lost + 0.6 and not at:  # (the poses are back)
            at.append(column or (sim.x, sim.y))
            if "parked" in where:
                below.append((*at[0], 0.0))

    records, events = flown_with_reports(ctrl, sim, lost + 8.0,
                                         Mocap(MocapNoise(pos_std=0.001, dropouts=((lost, lost + 0.6),))),
                                         hook, zenoh_router, zsession)
    assert ctrl.machine.sequence()[-2:] == [Mode.EMERGENCY_LANDING, Mode.DONE], ctrl.machine.sequence()
    assert not sim.airborne and sim.last_impact_speed < 0.7
    heard = [(e.kind, e.detail, e.node) for e in events]
    before = "taking_off" if column else "flying"
    assert heard[0] == ("emergency_landing", f"from {before}", ""), heard
    down = math.dist((sim.x, sim.y), at[0])
    if not below:
        assert down < 0.06, down  # where it was
        assert len(heard) == 1, heard
        return
    low = [r for r in records if r.t > lost + 0.6 and r.truth.z < 0.3]
    assert low and min(math.dist((r.truth.x, r.truth.y), at[0]) for r in low) >= width - 0.01
    assert width <= down <= ASIDE_REACH, down
    assert sim.y == pytest.approx(0.45, abs=0.03)  # under its flight
    assert len(heard) == 2 and heard[1][0] == "emergency_landing" and heard[1][2] == ASIDE, heard
    assert heard[1][1].startswith("poses back: landing beside a body in its column at ("), heard
    spot = events[1].at
    assert spot is not None and spot[2] == 0.0 and math.dist((sim.x, sim.y), spot[:2]) < 0.03, spot


@pytest.mark.timeout(60)
def test_a_planned_landing_a_lost_link_sends_elsewhere_is_reported_where_it_goes(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    """cf2's link is lost in its plan's landing onto l2: that landing goes on, no event (its
    mode stays `landing`). With a vehicle parked on l2 it lands on l1 instead
    (`_planned_landing_blocked`), and its executor says so, as for any fault landing: "link_lost
    from landing: landing at l1", naming the node and where it is (what the mission plans the
    others around)."""
    t0 = 0.5
    lost = t0 + [s.t for s in STEPS if s.node == "a2"][-1] + 0.5  # (half a second into its landing)
    sim = SimFlyingCar("cf2", MODEL, pos=STEPS[0].pos, yaw=0.0)
    below: list[tuple[float, float, float]] = []
    ctrl = VehicleController("cf2", MODEL, owner="e1", bodies=lambda: below)
    ctrl.load(plan_for("cf2", STEPS, MODEL, t0=t0))

    def hook(now: float) -> None:
        if round(now / 0.01) % 10 == 0:
            ctrl.on_telemetry(Telemetry(vid="cf2", t=now, gateway="sim", vbat=4.0, link_quality=1.0, sent=0,
                                        dropped=0, cmd_rate_hz=100.0, link_ok=now < lost), now)
        if now >= lost + 1.0 and not below:  # (the link judged lost: its landing goes on, then the body)
            below.append((*PADS["l2"][:2], 0.0))

    _, events = flown_with_reports(ctrl, sim, lost + 10.0, Mocap(), hook, zenoh_router, zsession, telemetry_every=0)
    assert ctrl.mode == Mode.DONE and math.dist((sim.x, sim.y, sim.z), PADS["l1"]) < 0.03, (sim.x, sim.y, sim.z)
    heard = [(e.kind, e.detail, e.node, e.at) for e in events]
    assert heard == [("link_lost", "from landing: landing at l1", "l1", PADS["l1"])], heard
