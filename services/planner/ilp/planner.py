"""Multi-commodity flow ILP planner (paper 000 §V-E, Alg. 3, eq. 6-7; Yu & LaValle 2015).

`plan_ilp` solves the time-expanded network model (ilp_network, ilp_arcs, ilp_model) with HiGHS on
the one-time-step graph (services/planner/graph/fleet_graph.py: nodes spaced about one step apart at
each edge kind's speed, rounded up), where every edge takes exactly one step dt.

Horizon policy. The cost of the best plan within T steps never increases with T (a plan for T
extends to T+1 by staying at the goals, which is free), but a longer horizon makes a bigger model.
1. Start at T = max(fewest steps of any vehicle within its battery, steps of any vehicle's
   individually cheapest route): the smallest horizon where every vehicle can take its own cheapest
   route, and where any plan exists at all.
2. While infeasible, grow T by 1, 2, 4, ... (an infeasible horizon proves nothing about cost, and a
   feasible longer horizon is at least as cheap as any shorter one). In a well-formed infrastructure
   (§V-D) moving the vehicles one at a time is a plan, so sum of the fewest steps (+ slack) bounds it.
3. The first feasible horizon may still be beaten by a longer one (waiting is not free, but a longer
   horizon allows cheaper detours). The sum of the vehicles' individually cheapest routes is a lower
   bound for every horizon; if the plan reaches it (within the MIP gap) it is optimal for all
   horizons. Otherwise T + 1, T + 2, T + 4 are tried, stopping at the first that does not improve,
   and the cheapest plan is kept. Each starts from the best plan so far (carried over, so it can
   only improve) and gets at most twice the time spent so far (at least 1 s) within the time limit.
At the time limit the best plan so far is returned with its gap, or, with none, a failure saying so.
The reported `mip_gap` is the proven gap on the chosen horizon (HiGHS's, or the first plan's against
the horizon's lower bound when HiGHS stopped first); `stats["lower_bound"]` is the horizon-free bound.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from common.domain.planfile import PathEntry, Task
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.ilp.arcs import arc_table
from services.planner.ilp.network import STAY, Fleet, battery_horizons, time_step
from services.planner.ilp.solve import MIP_REL_GAP, ColumnFilter, HorizonResult, relative_gap, solve_horizon
from services.planner.result import PlanResult, battery_shortfall

EXTENSIONS = (1, 2, 4)  # extra steps tried after the first feasible horizon
EXTENSION_FACTOR, EXTENSION_MIN_S = 2.0, 1.0  # an extension's time limit: this times the time so far, at least
PRIORITY_ORDERS = 8  # prioritized first plans tried per horizon


def cheapest_routes(graph: FleetGraph, fleet: Fleet) -> tuple[np.ndarray, np.ndarray]:
    """Per vehicle the eq. 3 cost and the number of steps of its individually cheapest route (over
    the edges its capabilities allow)."""
    n = graph.n_nodes
    cost = np.full(len(fleet.goals), np.inf)
    steps = np.zeros(len(fleet.goals), dtype=np.int64)
    masks, group = np.unique(fleet.allowed, axis=0, return_inverse=True)
    for m, mask in enumerate(masks):  # one Dijkstra per kind of vehicle
        members = np.flatnonzero(group.ravel() == m)
        edges = graph.edges[mask]
        weights = csr_matrix((fleet.move_cost[mask], (edges[:, 0], edges[:, 1])), shape=(n, n))
        dist, pred = dijkstra(weights, indices=fleet.starts[members], return_predecessors=True)
        for row, i in enumerate(members):
            cost[i] = dist[row, fleet.goals[i]]
            node = fleet.goals[i]
            while np.isfinite(cost[i]) and node != fleet.starts[i]:
                node = pred[row, node]
                steps[i] += 1
    return cost, steps


def decode(graph: FleetGraph, fleet: Fleet, vids: list[str], res: HorizonResult) -> tuple[dict[str, list[PathEntry]], float]:
    """Paths (an entry per step, waits included, ending at the arrival) and their eq. 3 cost."""
    cols, dt = res.columns, fleet.dt
    chosen = res.chosen[cols.kind[res.chosen] != STAY]
    chosen = chosen[np.lexsort((cols.step[chosen], cols.veh[chosen]))]
    paths: dict[str, list[PathEntry]] = {}
    total = 0.0
    for i, vid in enumerate(vids):
        arcs = chosen[cols.veh[chosen] == i]
        goal = fleet.goals[i]
        keep = len(arcs)
        while keep and cols.tail[arcs[keep - 1]] == goal and cols.head[arcs[keep - 1]] == goal:
            keep -= 1  # a trailing wait at the goal: the vehicle sits there anyway
        arcs = arcs[:keep]
        paths[vid] = [PathEntry(graph.ids[fleet.starts[i]], 0.0)] + [
            PathEntry(graph.ids[cols.head[j]], float((cols.step[j] + 1) * dt)) for j in arcs
        ]
        total += float(cols.cost[arcs].sum())
    return paths, total


def priority_orders(lower: np.ndarray, seed: int, count: int = PRIORITY_ORDERS) -> list[list[int]]:
    """Vehicle orders for the prioritized first plans: costliest route first, then seeded shuffles."""
    rng = np.random.default_rng(seed)
    first = [int(i) for i in np.argsort(-lower, kind="stable")]
    return [first] + [[int(i) for i in rng.permutation(len(lower))] for _ in range(count - 1)]


def plan_ilp(graph: FleetGraph, tasks: dict[str, Task], mu: float, time_limit: float, seed: int) -> PlanResult:
    """Optimal plan (to the MIP gap, for the horizon policy above) minimising eq. 7 subject to eq. 6."""
    t0 = time.perf_counter()
    deadline = t0 + time_limit
    vids = list(tasks)
    if time_step(graph) is None:
        return PlanResult(ok=False, planning_time_s=time.perf_counter() - t0,
                          error=f"the ILP plans on a graph where every edge takes one time step (§V-E); "
                                f"{graph.name!r} has edges of different durations: use its uniform-time-step graph")
    fleet = Fleet.of(graph, [tasks[v].start for v in vids], [tasks[v].goal for v in vids], mu,
                     [tasks[v].capabilities for v in vids], [tasks[v].usable_ah(graph.model) for v in vids])
    return plan_fleet(graph, fleet, tasks, deadline, seed, t0)


def plan_fleet(graph: FleetGraph, fleet: Fleet, tasks: dict[str, Task], deadline: float, seed: int, t0: float,
               allowed: ColumnFilter | None = None, delays: np.ndarray | None = None, slack_steps: int = 0) -> PlanResult:
    """The horizon policy above for `fleet` (the vehicles of `tasks`, in order), until `deadline`
    (perf_counter). For replanning (`ilp/replan.py`): `allowed` masks the columns a plan may use,
    `delays` (steps, per vehicle) is how long each must wait at its start first, and `slack_steps`
    widens the horizons tried (a closure in time may need the plan to wait it out)."""
    vids = list(tasks)

    def failure(error: str, vid: str = "") -> PlanResult:
        return PlanResult(ok=False, error=error, failed_vehicle=vid, planning_time_s=time.perf_counter() - t0)

    wait = np.zeros(len(vids), dtype=np.int64) if delays is None else delays
    fewest, least_charge = battery_horizons(graph, fleet)
    for i in np.flatnonzero(fewest < 0):
        task = tasks[vids[i]]
        if not np.isfinite(least_charge[i]):
            return failure(f"{vids[i]}: no route from {task.start} to {task.goal}", vids[i])
        return failure(f"{vids[i]}: {battery_shortfall(task, float(least_charge[i]), float(fleet.usable[i]))}", vids[i])
    table = arc_table(graph)
    lower, cheap_steps = cheapest_routes(graph, fleet)
    bound = float(lower.sum())
    orders = priority_orders(lower, seed)
    horizon = int(max((fewest + wait).max(), (cheap_steps + wait).max()))
    cap = max(horizon, int(fewest.sum() + wait.max())) + len(vids) + slack_steps
    solves: list[HorizonResult] = []

    def run(t: int, limit: float, previous: HorizonResult | None = None) -> HorizonResult:
        solves.append(solve_horizon(graph, table, fleet, t, limit, seed, orders, previous, allowed=allowed))
        return solves[-1]

    best = run(horizon, deadline - time.perf_counter())
    grow = 1
    while best.status == "infeasible":
        if horizon >= cap or time.perf_counter() >= deadline:
            return failure(f"no collision-free plan within {horizon} steps of {fleet.dt:g} s "
                           f"({len(solves)} horizons tried in {time.perf_counter() - t0:.2f} s)")
        horizon = min(horizon + grow, cap)
        grow *= 2
        best = run(horizon, deadline - time.perf_counter())
    if best.status == "timeout":
        return failure(f"time limit reached before a feasible plan within {horizon} steps")

    budget = max(EXTENSION_MIN_S, EXTENSION_FACTOR * (time.perf_counter() - t0))
    for extra in EXTENSIONS:
        left = deadline - time.perf_counter()
        if relative_gap(best.objective, bound) <= MIP_REL_GAP or left <= 0:
            break
        res = run(horizon + extra, min(left, budget), best)
        if res.status not in ("optimal", "feasible") or res.objective >= best.objective * (1 - MIP_REL_GAP):
            break
        best = res

    paths, cost = decode(graph, fleet, vids, best)
    model = {f"model_{k}": float(v) for k, v in vars(best.size).items()} if best.size else {}
    return PlanResult(
        ok=True, paths=paths, cost=cost, planning_time_s=time.perf_counter() - t0, mip_gap=best.gap,
        stats={
            "horizon": float(best.horizon), "first_horizon": float(horizon), "horizons_tried": float(len(solves)),
            "highs_solves": float(sum(s.size is not None for s in solves)), "columns": float(len(best.columns)),
            "lower_bound": bound, "timed_out": float(best.status == "feasible"),
            "build_s": sum(s.build_s for s in solves), "solve_s": sum(s.solve_s for s in solves), **model,
        },
    )
