"""One horizon of the ILP of paper 000 §V-E (Alg. 3): network, first plan, pruning, model, HiGHS.

1. The vehicles' columns within their battery (ilp_network).
2. A first plan in the same network: the cheapest of a few prioritized plans (ilp_priority) and the
   previous horizon's plan carried over. If its cost meets the horizon's lower bound (the vehicles'
   least costs, ignoring each other) within the MIP gap, it is optimal and HiGHS is not needed;
   otherwise it bounds the cost: columns no plan that cheap can use are dropped, and HiGHS gets its
   cost as the objective bound (a cutoff: handing it over as a MIP start instead cost HiGHS up to
   seconds of processing on large models).
3. The model (ilp_model), solved by HiGHS single-threaded with a time limit and a relative MIP gap.
   With a first plan presolve is off (on these pruned models it took far longer than the solve);
   without one the horizon may well be infeasible, and presolve's probing proves that much faster.
The result is the cheaper of HiGHS's plan and the first plan; its gap is against the larger of
HiGHS's dual bound and the horizon's lower bound. HiGHS does not always stop at its time limit
during its setup on models of 10^5 columns, so a call may overrun it by seconds there.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import highspy
import numpy as np

from services.planner.graph.fleet_graph import FleetGraph
from services.planner.ilp.arcs import ArcTable
from services.planner.ilp.first_plan import prioritized
from services.planner.ilp.network import Columns, Fleet, carry_over, least_costs, vehicle_columns, within_cost
from services.planner.ilp.program import ModelSize, build_lp

Status = Literal["optimal", "feasible", "infeasible", "timeout"]
ColumnFilter = Callable[[Columns], np.ndarray]
"""The mask of the columns a plan may use (replanning: closures in space-time, waits imposed)."""

MIP_REL_GAP = 1e-4


@dataclass(frozen=True)
class HorizonResult:
    """`optimal`: solved to the MIP gap; `feasible`: a plan, but the time limit stopped HiGHS before
    the gap; `timeout`: stopped without a plan; `infeasible`: no plan within `horizon` steps."""

    horizon: int
    status: Status
    columns: Columns
    chosen: np.ndarray  # indices of the columns set to 1 (empty without a plan)
    objective: float
    gap: float
    size: ModelSize | None  # None when the prioritized plan was already optimal
    build_s: float
    solve_s: float


def relative_gap(upper: float, lower: float) -> float:
    """(upper - lower) / |upper|, with float noise (below 1e-12 relative) read as zero."""
    gap = max(0.0, upper - lower) / max(abs(upper), 1e-12)
    return gap if gap > 1e-12 else 0.0


def _run_highs(cols: Columns, table: ArcTable, fleet: Fleet, horizon: int, n_nodes: int, cutoff: float | None,
               time_limit: float, seed: int, mip_rel_gap: float) -> tuple[highspy.Highs, ModelSize]:
    lp, size = build_lp(cols, table, fleet, horizon, n_nodes)
    h = highspy.Highs()
    options: list[tuple[str, object]] = [
        ("output_flag", False), ("threads", 1), ("random_seed", seed), ("time_limit", max(time_limit, 1e-3)),
        ("mip_rel_gap", mip_rel_gap), ("presolve", "on" if cutoff is None else "off"),
    ]
    if cutoff is not None:
        options.append(("objective_bound", cutoff * (1 + 1e-9) + 1e-12))
    for name, value in options:
        h.setOptionValue(name, value)
    h.passModel(lp)
    h.run()
    return h, size


def first_plan(cols: Columns, table: ArcTable, fleet: Fleet, horizon: int, n_nodes: int, park: bool,
               orders: list[list[int]], carried: np.ndarray | None, bound: float, mip_rel_gap: float) -> np.ndarray | None:
    """The cheapest of the carried-over plan and prioritized plans in `orders`, stopping early at the
    lower bound."""
    best = carried
    for order in orders:
        if best is not None and relative_gap(float(cols.cost[best].sum()), bound) <= mip_rel_gap:
            break
        plan = prioritized(cols, table, fleet, horizon, n_nodes, order, park)
        if plan is not None and (best is None or cols.cost[plan].sum() < cols.cost[best].sum()):
            best = plan
    return best


def solve_horizon(
    graph: FleetGraph, table: ArcTable, fleet: Fleet, horizon: int, time_limit: float, seed: int,
    orders: list[list[int]], previous: HorizonResult | None = None, mip_rel_gap: float = MIP_REL_GAP,
    allowed: ColumnFilter | None = None,
) -> HorizonResult:
    """Best plan within `horizon` steps. `orders`: vehicle orders for prioritized first plans;
    `previous`: a plan for a shorter horizon, carried over as a first plan; `allowed`: the columns
    a plan may use (all by default)."""
    t0 = time.perf_counter()
    cols = vehicle_columns(graph, fleet, horizon)
    if allowed is not None:
        cols = cols.subset(allowed(cols))
    bound = float(least_costs(graph, fleet, horizon).sum())
    carried = None
    if previous is not None and len(previous.chosen):
        carried = carry_over(previous.columns, previous.chosen, cols, horizon, fleet.goals, graph.n_nodes, graph.n_edges)
    start = first_plan(cols, table, fleet, horizon, graph.n_nodes, not graph.open_endpoints, orders, carried,
                       bound, mip_rel_gap)
    upper = float(cols.cost[start].sum()) if start is not None else np.inf
    if start is not None and relative_gap(upper, bound) <= mip_rel_gap:
        return HorizonResult(horizon, "optimal", cols, start, upper, relative_gap(upper, bound), None,
                             time.perf_counter() - t0, 0.0)
    if start is not None:
        keep = within_cost(graph, fleet, cols, horizon, upper)
        keep[start] = True
        start = np.searchsorted(np.flatnonzero(keep), start)
        cols = cols.subset(keep)
    t1 = time.perf_counter()
    h, size = _run_highs(cols, table, fleet, horizon, graph.n_nodes, upper if start is not None else None,
                         time_limit - (t1 - t0), seed, mip_rel_gap)
    t2 = time.perf_counter()
    status, info = h.getModelStatus(), h.getInfo()
    infeasible = status in (highspy.HighsModelStatus.kInfeasible, highspy.HighsModelStatus.kUnboundedOrInfeasible)
    if infeasible and start is None:
        return HorizonResult(horizon, "infeasible", cols, np.zeros(0, np.int64), np.inf, np.inf, size, t1 - t0, t2 - t1)
    if not infeasible and status not in (highspy.HighsModelStatus.kOptimal, highspy.HighsModelStatus.kTimeLimit):
        raise RuntimeError(f"HiGHS stopped with {h.modelStatusToString(status)} on horizon {horizon}")
    chosen, objective = (start, upper) if start is not None else (np.zeros(0, np.int64), np.inf)
    if info.primal_solution_status == highspy.SolutionStatus.kSolutionStatusFeasible:
        found = np.flatnonzero(np.asarray(h.getSolution().col_value) > 0.5)
        if cols.cost[found].sum() < objective:
            chosen, objective = found, float(cols.cost[found].sum())
    if not len(chosen):
        return HorizonResult(horizon, "timeout", cols, chosen, np.inf, np.inf, size, t1 - t0, t2 - t1)
    # infeasible with a cutoff: HiGHS proved nothing is cheaper than the first plan
    dual = objective if infeasible else float(info.mip_dual_bound)
    kind: Status = "feasible" if status == highspy.HighsModelStatus.kTimeLimit else "optimal"
    return HorizonResult(horizon, kind, cols, chosen, objective, relative_gap(objective, max(dual, bound)), size,
                         t1 - t0, t2 - t1)
