"""`AsyncFleet`: the asyncio flavour of the API. One zenoh session (a client of the fleet's router,
in the mission role) watching every vehicle's state and telemetry and the live missions; plans
asked of the planner (`planner/plan`); missions run by the fleet's own mission runner as a process
(`services/api/_mission.py`); single-vehicle commands as one-vehicle missions of that runner."""

from __future__ import annotations

import asyncio
import math
import os
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Literal

import msgspec
import yaml
import zenoh

from common.bus.args import credentials
from common.bus.keys import DEFAULT_FLEET, Keys
from common.bus.liveliness import AliveSet, watch_alive
from common.bus.messages import (
    GraphReply,
    GraphRequest,
    MissionAbort,
    PlanReply,
    PlanRequest,
    Pose,
    TaskAdd,
    TaskAddReply,
    TeamTask,
    Telemetry,
    VehicleState,
)
from common.bus.pubsub import SERVICE_START_S, Publisher, QueryError, Subscription, query, subscribe
from common.bus.session import ZenohConfig, open_session
from common.domain.mapfile import load_map, spot_pose
from common.domain.planfile import Plan, PlanGraph, Task
from common.domain.team_plan import TeamPlan
from common.errors import InputError
from services.api._errors import (
    CommandRefused,
    ConnectError,
    MissionFailed,
    PlanningError,
    UnknownVehicle,
    VehicleBusy,
)
from services.api._local import LocalStack
from services.api._mission import Mission
from services.api._types import MissionEvent, MissionResult, VehicleInfo

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where `fleet up` puts the router."""
FLEET_UP_SECRETS = Path(".fleet/secrets")
"""Where `fleet up` keeps the role credentials (used when the environment names none)."""
STALE_S = 2.0
"""A vehicle whose executor has said nothing for this long is not listed."""
ON_SPOT_M = 0.1
"""A vehicle this close (horizontally, and within it in height) to a spot stands on it."""
GOAL_CLEAR_M = 0.15
"""A single-vehicle command's goal is taken when another vehicle is this close to it."""
PLAN_WAIT_S = 30.0
"""How long a single-vehicle command waits for the mission runner to hand out its plan."""
PLANNER_MARGIN_S = 10.0
"""The planner's answer may come this much later than the planning time limit."""
AT_REST_ON_GROUND = frozenset({"idle", "parked", "done", "holding"})
HOVER_M = 0.1
"""A vehicle this close to an air node, flying, after its planned arrival, hovers there."""
HOVER_MARGIN_S = 15.0
"""How much later than planned a vehicle may reach the air node it was sent to."""
ADD_WAIT_S = 5.0
"""How long `add_task` waits for the running mission's answer."""
IDLE = "idle"
"""The mode of a vehicle no executor controls yet (no plan since the fleet started): it sits where
its motion-capture pose says."""



class _Flight:
    """A vehicle in the air after `takeoff`: its hover mission and the spot it took off from."""

    def __init__(self, mission: Mission, map: str, start: str) -> None:
        self.mission, self.map, self.start = mission, map, start


class AsyncFleet:
    """A connection to a fleet (and the fleet itself, when `start` brought it up here).

    Make one with `connect`, `start` or `open`; use it as an async context manager, or `close` it."""

    def __init__(self, zconfig: ZenohConfig, keys: Keys, map: str = "town", local: LocalStack | None = None) -> None:
        self.keys = keys
        self.map = map
        """The map single-vehicle commands and `vehicles` spots refer to unless told otherwise."""
        self._zconfig = zconfig
        self._local = local
        self._session: zenoh.Session | None = None
        self._subs: list[Subscription] = []
        self._states: dict[str, VehicleState] = {}
        self._heard: dict[str, float] = {}
        self._telemetry: dict[str, Telemetry] = {}
        self._poses: dict[str, Pose] = {}
        self._missions: AliveSet | None = None
        self._running: dict[str, Mission] = {}
        self._maps: dict[str, str] = {}
        """Mission id -> map, for the missions started here."""
        self._flights: dict[str, _Flight] = {}
        """Vehicles in the air after `takeoff`, by id."""
        self._graphs: dict[str, PlanGraph] = {}
        self._tmp = tempfile.TemporaryDirectory(prefix="fleet-api-")

    # ---- making one ---------------------------------------------------------------------------
    @classmethod
    async def connect(cls, endpoint: str | None = None, fleet: str | None = None, *, map: str = "town",
                      secrets: str | Path | None = None, role: str = "mission") -> AsyncFleet:
        """Connect to a running fleet (`fleet up`, compose, a lab's). Defaults: the endpoint of
        FLEET_ZENOH_CONNECT or `fleet up`'s (tcp/127.0.0.1:7447), the fleet FLEET_NAME or "default",
        credentials from FLEET_ZENOH_USER / FLEET_ZENOH_PASSWORD(_FILE), else from `secrets` (a
        credentials directory; default `fleet up`'s .fleet/secrets if it exists) as `role`."""
        endpoint = endpoint or os.environ.get("FLEET_ZENOH_CONNECT", DEFAULT_ENDPOINT)
        try:
            user, password = credentials()
        except InputError as exc:
            raise ConnectError(str(exc)) from None
        secrets_dir = Path(secrets) if secrets is not None else FLEET_UP_SECRETS
        if user is None and (secrets is not None or secrets_dir.exists()):
            try:
                user, password = role, (secrets_dir / f"zenoh-{role}").read_text().strip()
            except OSError as exc:
                raise ConnectError(f"{secrets_dir}: no password for role {role!r} ({exc.strerror})") from None
        connect = tuple(e.strip() for e in endpoint.split(",") if e.strip())
        zconfig = ZenohConfig.client(*connect, user=user, password=password)
        try:
            keys = Keys(fleet or os.environ.get("FLEET_NAME", DEFAULT_FLEET))
        except ValueError as exc:
            raise ConnectError(str(exc)) from None
        self = cls(zconfig, keys, map)
        await self._open()
        return self

    @classmethod
    async def start(cls, run_dir: str | Path = "out/api-fleet", *, radios: str | Path | None = None,
                    map: str = "town", executors: int = 2, profiles: Iterable[str] = (),
                    only: Iterable[str] | None = None, overrides: Mapping[str, str] | None = None,
                    fleet: str = "api", timeout_s: float = 60.0) -> AsyncFleet:
        """Start a simulated fleet here (compose.yaml's services as local processes, as `fleet up`
        does; logs and recordings under `run_dir`) and connect to it; `close` stops it. `radios`: a
        radios file (default compose.yaml's, the town's 8 flying cars); `profiles=["team"]` adds the
        simulated ground-air team; `only`: just these services; `overrides`: compose variables."""
        try:
            stack = await asyncio.to_thread(LocalStack, Path(run_dir), fleet, Path(radios) if radios else None,
                                            executors, profiles, only, dict(overrides or {}), timeout_s)
        except (RuntimeError, InputError) as exc:
            raise ConnectError(f"the fleet did not start: {exc}") from None
        self = cls(stack.local.client_config(), stack.local.keys, map, stack)
        try:
            await self._open()
        except ConnectError:
            await asyncio.to_thread(stack.close)
            raise
        return self

    @classmethod
    async def open(cls, **start_options) -> AsyncFleet:
        """`connect` when the environment names a fleet (FLEET_ZENOH_CONNECT), else `start` one
        here with `start_options`: what a script or notebook that runs anywhere wants."""
        if os.environ.get("FLEET_ZENOH_CONNECT"):
            return await cls.connect(map=start_options.get("map", "town"))
        return await cls.start(**start_options)

    async def _open(self) -> None:
        try:
            self._session = await asyncio.to_thread(open_session, self._zconfig)
        except zenoh.ZError as exc:
            raise ConnectError(f"cannot reach the fleet's router at {', '.join(self._zconfig.connect)}: {exc}") from None
        k, s = self.keys, self._session
        self._subs = [subscribe(s, k.all_vehicles("state"), VehicleState, self._on_state, maxlen=4096),
                      subscribe(s, k.all_vehicles("telemetry"), Telemetry, self._on_telemetry, maxlen=4096),
                      subscribe(s, k.all_vehicles("pose"), Pose, self._on_pose, maxlen=4096)]
        self._missions = await watch_alive(s, k, "mission")

    async def close(self) -> None:
        """Close the session; stop the fleet if `start` brought it up (running missions end with it)."""
        for mission in list(self._running.values()):
            if not mission.done:
                await mission.abort("the API is closing")
        if self._missions is not None:
            self._missions.close()
        for sub in self._subs:
            sub.close()
        if self._session is not None:
            self._session.close()
            self._session = None
        if self._local is not None:
            await asyncio.to_thread(self._local.close)
            self._local = None
        self._tmp.cleanup()

    async def __aenter__(self) -> AsyncFleet:
        return self

    async def __aexit__(self, *_exc: object) -> None:
        await self.close()

    @property
    def session(self) -> zenoh.Session:
        """The zenoh session, for what the API does not cover (keys: `keys`, messages: common/bus/messages.py)."""
        if self._session is None:
            raise ConnectError("the fleet connection is closed")
        return self._session

    # ---- what the fleet says ------------------------------------------------------------------
    def _on_state(self, state: VehicleState, _key: str) -> None:
        self._states[state.vid] = state
        self._heard[state.vid] = time.monotonic()
        for mission in list(self._running.values()):
            mission._on_fleet_state(state)

    def _on_telemetry(self, tel: Telemetry, _key: str) -> None:
        self._telemetry[tel.vid] = tel

    def _on_pose(self, pose: Pose, _key: str) -> None:
        self._poses[pose.vid] = pose
        self._heard[pose.vid] = time.monotonic()

    def _owner_mission(self, vid: str) -> str | None:
        """The running mission that owns `vid`, if any: one of ours, or one whose runner is alive
        and whose plan the vehicle holds."""
        for mission in self._running.values():
            if not mission.done and vid in mission.vehicles:
                return mission.id
        state = self._states.get(vid)
        if state is not None and state.mission and self._missions is not None \
                and state.mission in self._missions.instances:
            return state.mission
        return None

    def _info(self, vid: str) -> VehicleInfo:
        """From its executor's state; a vehicle no executor controls yet from its pose (mode `IDLE`)."""
        s, pose, tel = self._states.get(vid), self._poses.get(vid), self._telemetry.get(vid)
        where = s if s is not None else pose
        assert where is not None
        return VehicleInfo(vid=vid, mode=s.mode if s else IDLE, x=where.x, y=where.y, z=where.z, yaw=where.yaw,
                           mission=s.mission if s else "", busy=self._owner_mission(vid) is not None,
                           arrived=s.arrived if s else False, owner=s.owner if s else "",
                           battery_v=tel.vbat if tel else None, link_quality=tel.link_quality if tel else None,
                           capabilities=tel.capabilities if tel else "fly+drive", t=where.t)

    async def vehicles(self, expect: Iterable[str] | int = 1, timeout: float = 5.0) -> dict[str, VehicleInfo]:
        """Every vehicle the fleet sees now (its executor's state, or its motion-capture pose), by id. Waits up to `timeout` s until the ids in
        `expect` (or that many vehicles) are heard, with their telemetry; then returns what is known."""
        want = expect if isinstance(expect, int) else None
        ids = set() if isinstance(expect, int) else set(expect)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            live = self._live()
            if ids <= live and (want is None or len(live) >= want) and live <= set(self._telemetry):
                break
            await asyncio.sleep(0.05)
        return {vid: self._info(vid) for vid in sorted(self._live())}

    def _live(self) -> set[str]:
        now = time.monotonic()
        return {vid for vid, t in self._heard.items() if now - t < STALE_S}

    def vehicle(self, vid: str) -> VehicleInfo:
        """One vehicle now; `UnknownVehicle` if the fleet does not see it."""
        if vid not in self._live():
            raise UnknownVehicle(vid, "neither an executor nor motion capture reports it")
        return self._info(vid)

    def telemetry(self, vid: str) -> Telemetry | None:
        """The latest telemetry of `vid` from its gateway (battery, link, firmware), or None."""
        return self._telemetry.get(vid)

    # ---- planning ------------------------------------------------------------------------------
    async def plan(self, map: str, tasks: Mapping[str, Task | tuple[str, str] | str], *, planner: str = "sipp",
                   mu: float = 0.5, time_limit: float = 30.0) -> Plan:
        """Plan `tasks` (vehicle -> Task, (start, goal), or a goal from the spot the vehicle stands
        on) on `map` with the fleet's planner ("sipp", "ilp"); the validated plan. Nothing moves.
        `PlanningError` says why it failed."""
        request = PlanRequest(map=map, tasks=await self._tasks(map, tasks), planner=planner, mu=mu,
                              time_limit=time_limit)
        reply = await self._ask_planner(request, time_limit)
        if reply.plan is None:
            raise PlanningError("the planner's reply carries no plan")
        return reply.plan

    async def plan_team(self, map: str, team: TeamTask, *, time_limit: float = 30.0) -> TeamPlan:
        """Plan a ground-air team (paper 002, the "collab" planner) on a collab map; the team plan."""
        request = PlanRequest(map=map, tasks={}, planner="collab", time_limit=time_limit, team=team)
        reply = await self._ask_planner(request, time_limit + team.improve_s)
        if reply.team_plan is None:
            raise PlanningError("the planner's reply carries no team plan")
        return reply.team_plan

    async def _tasks(self, map: str, tasks: Mapping[str, Task | tuple[str, str] | str]) -> dict[str, Task]:
        """Tasks as the planner takes them; a goal alone starts from the spot the vehicle stands on."""
        out = {}
        for vid, t in tasks.items():
            if isinstance(t, str):
                await self.vehicles([vid], timeout=STALE_S)
                info = self.vehicle(vid)
                t = Task(start=self._spot_of(info, map), goal=t, capabilities=info.capabilities)  # type: ignore[arg-type]
            out[vid] = t if isinstance(t, Task) else Task(start=t[0], goal=t[1])
        return out

    async def _graph(self, map: str) -> PlanGraph:
        """The planner's graph of `map` (`planner/graph`), asked once."""
        if map not in self._graphs:
            try:
                reply = await query(self.session, self.keys.planner_graph, GraphRequest(map=map), GraphReply,
                                    timeout=PLANNER_MARGIN_S, find_s=SERVICE_START_S)
            except QueryError as exc:
                raise PlanningError(f"the planner is unreachable or failed: {exc}") from None
            if not reply.ok or reply.graph is None:
                raise PlanningError(reply.error or "the planner's reply carries no graph")
            self._graphs[map] = reply.graph
        return self._graphs[map]

    async def _ask_planner(self, request: PlanRequest, time_limit: float) -> PlanReply:
        wait = time_limit + PLANNER_MARGIN_S
        try:
            reply = await query(self.session, self.keys.planner_plan,
                                msgspec.structs.replace(request, reply_within=wait), PlanReply,
                                timeout=wait, find_s=SERVICE_START_S)
        except QueryError as exc:
            raise PlanningError(f"the planner is unreachable or failed: {exc}") from None
        if not reply.ok:
            raise PlanningError(reply.error)
        return reply

    # ---- missions ------------------------------------------------------------------------------
    async def start_mission(self, map: str, tasks: Mapping[str, Task | tuple[str, str] | str], *, planner: str = "sipp",
                            mu: float = 0.5, time_limit: float = 30.0, keep_going: bool = False,
                            lifelong_minutes: float = 0.0, seed: int = 0, rejoins: int | None = None,
                            on_event: Callable[[MissionEvent], None] | None = None) -> Mission:
        """Start a mission of flying cars: the fleet's mission runner plans `tasks` (as in `plan`)
        on `map`, hands the plans out, starts every vehicle together and watches (one vehicle's
        fault: the others are planned on around it; a fault they cannot be planned around aborts
        it, unless `keep_going`).
        `lifelong_minutes`: for that long, every vehicle that arrives gets a random free parking spot
        as its next goal (then the last tasks are flown out), drawn with `seed` (the same seed, the
        same sequence of choices; unused without `lifelong_minutes`); `add_task` gives one a goal of yours.
        `rejoins`: how often a vehicle held for another's sake, or stopped by a fault that cleared,
        may be brought back into the plan once its way is clear (None: the runner's default, 3; 0:
        it stays held).
        Returns at once; `on_event` is called with each `MissionEvent` (on the event loop).
        `VehicleBusy` if another running mission owns one of the vehicles."""
        if lifelong_minutes < 0:
            raise ValueError(f"lifelong_minutes must not be negative, got {lifelong_minutes}")
        if rejoins is not None and rejoins < 0:
            raise ValueError(f"rejoins must be 0 or more, got {rejoins}")
        extra = ["--lifelong", "--minutes", repr(lifelong_minutes), "--seed", str(seed)] if lifelong_minutes else []
        extra += ["--rejoins", str(rejoins)] if rejoins is not None else []
        return await self._start(map, tasks, planner, mu, time_limit, keep_going, on_event, extra)

    async def _start(self, map: str, tasks: Mapping[str, Task | tuple[str, str] | str], planner: str, mu: float,
                     time_limit: float, keep_going: bool, on_event: Callable[[MissionEvent], None] | None,
                     extra: list[str]) -> Mission:
        for vid in tasks:
            self._check_free(vid)
        tasks = await self._tasks(map, tasks)
        mission = f"api-{uuid.uuid4().hex[:8]}"
        scenario = Path(self._tmp.name) / f"{mission}.yaml"
        scenario.write_text(yaml.safe_dump({"map": map, "tasks": msgspec.to_builtins(tasks)}))
        args = ["run", str(scenario), "--id", mission, "--planner", planner, "--mu", repr(mu),
                "--time-limit", repr(time_limit), *(["--keep-going"] if keep_going else []), *extra]
        self._maps[mission] = map
        return await self._launch(mission, list(tasks), args, on_event)

    async def start_team_mission(self, map: str, team: TeamTask, *, time_limit: float = 30.0,
                                 on_event: Callable[[MissionEvent], None] | None = None) -> Mission:
        """Start a ground-air team mission (paper 002) through the executors: the drone and the UGV
        of `team` on the collab `map`."""
        for vid in (team.drone, team.ugv):
            self._check_free(vid)
        mission = f"api-{uuid.uuid4().hex[:8]}"
        vec = lambda v: ",".join(f"{c:g}" for c in v)  # noqa: E731
        args = ["team", "--id", mission, "--map", map, "--start", vec(team.drone_start), "--ugv", vec(team.ugv_start),
                "--goal", vec(team.goal), "--drone-id", team.drone, "--ugv-id", team.ugv, "--planner", team.method,
                "--time-limit", repr(time_limit), "--improve", repr(team.improve_s)]
        return await self._launch(mission, [team.drone, team.ugv], args, on_event)

    async def _launch(self, mission: str, vehicles: list[str], args: list[str],
                      on_event: Callable[[MissionEvent], None] | None) -> Mission:
        z = self._zconfig
        argv = [sys.executable, "-m", "services.cli", "mission", *args, "--connect", ",".join(z.connect),
                "--fleet", self.keys.fleet]
        env = {k: v for k, v in os.environ.items() if k != "FLEET_ZENOH_PASSWORD_FILE"}
        if z.user is not None and z.password is not None:
            env.update(FLEET_ZENOH_USER=z.user, FLEET_ZENOH_PASSWORD=z.password)
        run = Mission(self.session, self.keys, mission, vehicles, argv, env, on_event)
        self._running[mission] = run
        await run._launch()
        return run

    async def run_mission(self, map: str, tasks: Mapping[str, Task | tuple[str, str] | str], *, planner: str = "sipp",
                          mu: float = 0.5, time_limit: float = 30.0, keep_going: bool = False,
                          lifelong_minutes: float = 0.0, seed: int = 0, rejoins: int | None = None,
                          on_event: Callable[[MissionEvent], None] | None = None,
                          check: bool = True) -> MissionResult:
        """`start_mission` and wait for its result; `MissionFailed` (with the result) if not every
        vehicle arrived without contact, unless `check` is False."""
        mission = await self.start_mission(map, tasks, planner=planner, mu=mu, time_limit=time_limit,
                                           keep_going=keep_going, lifelong_minutes=lifelong_minutes, seed=seed,
                                           rejoins=rejoins, on_event=on_event)
        return self._checked(await mission.wait(), check)

    async def run_team_mission(self, map: str, team: TeamTask, *, time_limit: float = 30.0,
                               on_event: Callable[[MissionEvent], None] | None = None, check: bool = True) -> MissionResult:
        """`start_team_mission` and wait for its result (`MissionFailed` unless it succeeded or not `check`)."""
        mission = await self.start_team_mission(map, team, time_limit=time_limit, on_event=on_event)
        return self._checked(await mission.wait(), check)

    @staticmethod
    def _checked(result: MissionResult, check: bool) -> MissionResult:
        if check and not result.ok:
            raise MissionFailed(result.mission, result.reason, result)
        return result

    async def abort(self, mission: str, reason: str = "aborted through the API") -> None:
        """Abort any running mission by id (ours or another client's): every vehicle lands or stops."""
        if mission in self._running:
            await self._running[mission].abort(reason)
            return
        pub = Publisher(self.session, self.keys.mission(mission, "abort"), MissionAbort)
        pub.put(MissionAbort(mission=mission, reason=reason))
        await asyncio.sleep(0.1)
        pub.close()

    async def add_task(self, mission: str, vid: str, goal: str, *, timeout: float = ADD_WAIT_S) -> float:
        """Give `vid`, a vehicle of the running mission `mission` (its id, `Mission.id`), the new
        goal node `goal`, planned against the others' paths (it leaves its goal, or turns off its
        way); the mission time (s after its start) it is planned to arrive. `CommandRefused` names
        the vehicle and why: the mission's refusal (not in the mission, the goal is another's, no
        plan, ...), a goal where another vehicle stands, or no answer (the mission is not running)."""
        if mission in self._maps:
            graph = await self._graph(self._maps[mission])
            node = graph.nodes.get(goal)
            if node is not None:
                self._check_clear(vid, goal, node.pos[0], node.pos[1], node.pos[2])
        try:
            reply = await query(self.session, self.keys.mission(mission, "add"), TaskAdd(vid=vid, goal=goal),
                                TaskAddReply, timeout=timeout)
        except QueryError as exc:
            raise CommandRefused(vid, f"mission {mission} did not answer ({exc}): is it running?") from None
        if not reply.ok:
            raise CommandRefused(vid, reply.error)
        return reply.arrival_s

    # ---- single-vehicle commands -----------------------------------------------------------------
    def _check_clear(self, vid: str, goal: str, x: float, y: float, z: float) -> None:
        """CommandRefused when another vehicle stands (or hovers) on `goal`."""
        for other in self._live() - {vid}:
            o = self._info(other)
            if math.hypot(o.x - x, o.y - y) < GOAL_CLEAR_M and abs(o.z - z) < 2 * GOAL_CLEAR_M:
                raise CommandRefused(vid, f"{goal} is taken by {other}")

    def _check_free(self, vid: str) -> None:
        owner = self._owner_mission(vid)
        if owner is not None:
            state = self._states.get(vid)
            where = f" ({state.mode}, step {state.step}/{state.steps})" if state is not None and state.mission == owner else ""
            raise VehicleBusy(vid, owner, f"mission {owner} owns it{where}: wait for it or abort it first")

    def _spot_of(self, info: VehicleInfo, map: str) -> str:
        """The spot (parking or helipad) `info` stands on; CommandRefused if none."""
        spec = load_map(map)
        spots = [p.id for p in spec.parking] + [h.id for h in spec.helipads]
        if info.capabilities == "fly":
            spots += list(spec.roads.nodes)
        best, dist = "", math.inf
        for spot in spots:
            x, y, z, _ = spot_pose(spec, spot)
            d = math.hypot(info.x - x, info.y - y)
            if d < dist and abs(info.z - z) < ON_SPOT_M:
                best, dist = spot, d
        if dist > ON_SPOT_M:
            raise CommandRefused(info.vid, f"not on a spot of map {map!r} (the nearest is {best or 'none'} "
                                           f"{dist:.2f} m away): move it there first")
        return best

    async def go_to(self, vid: str, spot: str | tuple[float, float, float], *, map: str | None = None,
                    via: Literal["any", "drive", "fly"] = "any", time_limit: float = 10.0,
                    on_event: Callable[[MissionEvent], None] | None = None) -> MissionResult | None:
        """Take one vehicle from the spot it stands on to `spot` (a parking spot or helipad): a
        one-vehicle plan from the planner, flown through the executors as a mission (the same
        safety checks: faults abort and land it). `via="drive"` refuses a plan that takes off,
        `via="fly"` one that does not. While the vehicle hovers after `takeoff`: to an air node, or
        the air node nearest a point (x, y, z), where it then hovers (returns None once it is
        there); to a ground spot, it lands there (as `land`). Refused (`VehicleBusy`) while a
        running mission owns the vehicle; `CommandRefused` when it is not at rest on a spot or
        hovering, or `spot` is taken or unknown; `MissionFailed` if it did not get there."""
        flight = self._flights.get(vid)
        if flight is not None and not flight.mission.done:
            return await self._fly(vid, flight, spot)
        map = map or self.map
        await self.vehicles([vid], timeout=STALE_S)
        info = self.vehicle(vid)
        self._check_free(vid)
        if not isinstance(spot, str):
            raise CommandRefused(vid, f"a point {spot} is in the air: take off first")
        if info.mode not in AT_REST_ON_GROUND:
            raise CommandRefused(vid, f"is {info.mode}: a command starts from rest on the ground")
        start = self._spot_of(info, map)
        if spot == start:
            raise CommandRefused(vid, f"already on {spot}")
        try:
            x, y, z, _ = spot_pose(load_map(map), spot)
        except InputError as exc:
            raise CommandRefused(vid, str(exc)) from None
        self._check_clear(vid, spot, x, y, z)
        mu = {"any": 0.5, "drive": 1.0, "fly": 0.0}[via]  # all energy: it drives if it can; all time: it flies
        task = Task(start=start, goal=spot, capabilities=info.capabilities)  # type: ignore[arg-type]
        mission = await self.start_mission(map, {vid: task}, mu=mu, time_limit=time_limit, on_event=on_event)
        plan = await mission.plan_of(vid, PLAN_WAIT_S)
        if plan is not None and via != "any":
            flies = any(step.edge == "takeoff" for step in plan.steps)
            if flies != (via == "fly"):
                await mission.abort(f"{vid}: the plan does not {via}")
                raise CommandRefused(vid, f"the planner {'flies' if flies else 'drives'} from {start} to {spot}, "
                                          f"not {'drives' if via == 'drive' else 'flies'} (refused before the start)")
        result = await mission.wait()
        if not result.ok:
            raise MissionFailed(result.mission, f"{vid} did not get from {start} to {spot}: {result.reason}", result)
        return result

    async def drive_to(self, vid: str, spot: str, **options) -> MissionResult:
        """`go_to` on roads only: refused before the start if the plan would take off."""
        return await self.go_to(vid, spot, via="drive", **options)

    async def fly_to(self, vid: str, spot: str, **options) -> MissionResult:
        """Take off, fly and land at `spot` (`go_to` whose plan must take off)."""
        return await self.go_to(vid, spot, via="fly", **options)


    async def takeoff(self, vid: str, to: str | None = None, *, map: str | None = None, time_limit: float = 10.0,
                      on_event: Callable[[MissionEvent], None] | None = None) -> str:
        """Take off and hover: a one-vehicle mission from the spot the vehicle stands on to the air
        node `to` (default: the one above the nearest take-off point; a flying car drives there
        first), flown through the executors with the missions' safety checks; returns the air node
        once the vehicle hovers there. The mission stays open: `go_to` moves the vehicle in the air,
        `land` (or `go_to` a ground spot) ends it; closing the connection lands it. Refused
        (`VehicleBusy`) while a running mission owns the vehicle; `CommandRefused` when it is not at
        rest on a spot, cannot fly, or `to` is no air node; `MissionFailed` if it did not get up."""
        map = map or self.map
        await self.vehicles([vid], timeout=STALE_S)
        info = self.vehicle(vid)
        self._check_free(vid)
        if info.mode not in AT_REST_ON_GROUND:
            raise CommandRefused(vid, f"is {info.mode}: a take-off starts from rest on the ground")
        if info.capabilities == "drive":
            raise CommandRefused(vid, "only drives")
        start = self._spot_of(info, map)
        graph = await self._graph(map)
        goal = to or self._above(graph, info)
        if goal not in graph.nodes or graph.nodes[goal].kind != "air":
            raise CommandRefused(vid, f"{goal!r} is no air node of map {map!r}")
        self._check_clear(vid, goal, *graph.nodes[goal].pos)
        task = Task(start=start, goal=goal, capabilities=info.capabilities)  # type: ignore[arg-type]
        mission = await self._start(map, {vid: task}, "sipp", 0.5, time_limit, False, on_event, ["--hover"])
        plan = await mission.plan_of(vid, PLAN_WAIT_S)
        if plan is None:
            result = await mission.abort(f"{vid}: no plan to take off")
            raise MissionFailed(mission.id, f"{vid} did not take off: {result.reason}", result)
        self._flights[vid] = _Flight(mission, map, start)
        await self._hover_at(vid, mission, goal, plan.steps[-1].pos, plan.steps[-1].t)
        return goal

    async def land(self, vid: str, spot: str | None = None) -> MissionResult:
        """Land a vehicle that hovers after `takeoff` at `spot` (a parking spot or helipad; default:
        the spot it took off from) and end its mission once it is there: its result. Refused
        (`VehicleBusy`) while another mission owns the vehicle, `CommandRefused` when it is not
        flying after a `takeoff` of this connection or `spot` is taken; `MissionFailed` if it did
        not land there."""
        flight = self._flights.get(vid)
        if flight is None or flight.mission.done:
            self._check_free(vid)
            raise CommandRefused(vid, "is not in the air after a takeoff of this connection")
        return await self._fly(vid, flight, spot or flight.start)  # type: ignore[return-value]

    async def _fly(self, vid: str, flight: _Flight, spot: str | tuple[float, float, float]) -> MissionResult | None:
        """Move a hovering vehicle to an air node (it hovers there: None) or a ground spot (it
        lands and its mission ends: the result)."""
        graph = await self._graph(flight.map)
        if isinstance(spot, str):
            node = spot
            if node not in graph.nodes:
                raise CommandRefused(vid, f"no node {node!r} on map {flight.map!r}")
        else:
            node = min((n for n, g in graph.nodes.items() if g.kind == "air"), key=lambda n: math.dist(graph.nodes[n].pos, spot))
        pos, kind = graph.nodes[node].pos, graph.nodes[node].kind
        spots = ("parking", "helipad", "land") if self._info(vid).capabilities == "fly" else ("parking", "helipad")
        if kind != "air" and kind not in spots:
            raise CommandRefused(vid, f"{node} is a {kind} node: it lands on {' or '.join(spots)} nodes")
        mission = flight.mission
        arrival_s = await self.add_task(mission.id, vid, node)
        if kind == "air":
            await self._hover_at(vid, mission, node, pos, arrival_s)
            return None
        result = await mission.wait()
        self._flights.pop(vid, None)
        if not result.ok:
            raise MissionFailed(result.mission, f"{vid} did not land on {node}: {result.reason}", result)
        return result

    def _above(self, graph: PlanGraph, info: VehicleInfo) -> str:
        """The air node above the take-off point nearest the vehicle (CommandRefused if none)."""
        ups = [(u, a) for u, a, kind in graph.edges if kind == "takeoff"]
        if not ups:
            raise CommandRefused(info.vid, "the map has no take-off point")
        _, air = min(ups, key=lambda e: math.dist(graph.nodes[e[0]].pos, (info.x, info.y, info.z)))
        return air

    async def _hover_at(self, vid: str, mission: Mission, node: str, pos: tuple[float, float, float],
                        arrival_s: float) -> None:
        """Wait until `vid` hovers at `node` (flying, within `HOVER_M`, after its planned arrival);
        MissionFailed if its mission ends first or it is `HOVER_MARGIN_S` late."""
        deadline = time.monotonic() + PLAN_WAIT_S
        while True:
            if mission.done:
                result = await mission.wait()
                self._flights.pop(vid, None)
                raise MissionFailed(mission.id, f"{vid} did not reach {node}: {result.reason}", result)
            t0, s = mission._t0, self._states.get(vid)
            if t0 is not None:
                t0 += mission._delay  # (the plan's clock waited for vehicles behind their plans)
                now = time.time()
                if (now >= t0 + arrival_s and s is not None and s.mission == mission.id and s.mode == "flying"
                        and math.dist((s.x, s.y, s.z), pos) < HOVER_M):
                    return
                deadline = time.monotonic() + (t0 + arrival_s + HOVER_MARGIN_S - now)
            if time.monotonic() > deadline:
                where = f"{s.mode} at ({s.x:.2f}, {s.y:.2f}, {s.z:.2f})" if s is not None else "unheard"
                raise MissionFailed(mission.id, f"{vid} is not hovering at {node} in time ({where})")
            await asyncio.sleep(0.05)
