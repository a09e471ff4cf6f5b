"""Each vehicle's share of the time-expanded network (paper 000 §V-E, Alg. 3 line 2; Yu & LaValle
2015 §III-A), pruned to the arcs it can use within the horizon, its battery (eq. 6) and, once a plan
is known, its cost.

Steps k = 0..T-1 go from time k dt to (k+1) dt. A vehicle's columns are its move arcs (along an
edge), its wait arcs (n -> n) and its goal-stay arcs: a virtual node g* ("arrived") per vehicle,
entered from its goal g by a finish arc and kept by stay arcs. Physically both are a wait at g, but
they cost and draw nothing: the cost of eq. 7 is summed until each vehicle's arrival, so arriving
early is free (DESIGN.md: after its last entry a vehicle sits at its goal forever).

Pruning (the reachable sets of the brief, weighted): F[k, n] is the least weight (charge or cost)
with which the vehicle can be at n at time k, B[r, n] the least weight from n to its goal within r
steps; an arc from (u, k) to (v, k+1) of weight w is kept only if F[k, u] + w + B[T-k-1, v] fits the
budget. Infinite weight means unreachable in hops, so with the charge budget of eq. 6 this contains
the plain forward/backward BFS test dist(start, n) <= k and dist(n, goal) <= T - k. With a known
plan of cost U, an arc is useless to vehicle i if F + w + B for i plus the other vehicles' least
costs exceeds U (a bound-based reduction: every plan at least as cheap as U keeps its arcs).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from common.domain.vehicle_model import Capabilities
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.graph.memo import per_graph

TOL = 1e-9  # relative slack on budgets (float rounding)


def time_step(graph: FleetGraph) -> float | None:
    """The graph's time step: its `dt`, or the common duration of all its edges (MovingAI grids),
    or None when edges take different times (the ILP needs one step per edge, §V-E)."""
    if graph.dt is not None:
        return graph.dt
    if graph.n_edges and np.allclose(graph.duration, graph.duration[0], rtol=1e-9, atol=0.0):
        return float(graph.duration[0])
    return None


@dataclass(frozen=True)
class Fleet:
    """The vehicles as node indices, and what one step of each arc type costs and draws."""

    dt: float  # s per step
    starts: np.ndarray  # (V,)
    goals: np.ndarray  # (V,)
    move_cost: np.ndarray  # (E,) eq. 3 per traversal
    wait_cost: np.ndarray  # (N,) eq. 3 per step of waiting
    move_charge: np.ndarray  # (E,) eq. 4-5 per traversal
    wait_charge: np.ndarray  # (N,) eq. 4-5 per step of waiting
    usable: np.ndarray  # (V,) Ah, each vehicle's C_low budget of eq. 6 (what its battery still holds)
    allowed: np.ndarray  # (V, E) the edges each vehicle's capabilities allow

    @classmethod
    def of(cls, graph: FleetGraph, starts: list[str], goals: list[str], mu: float,
           capabilities: list[Capabilities] | None = None, usable: list[float] | None = None) -> Fleet:
        dt = time_step(graph)
        if dt is None:
            raise ValueError(f"graph {graph.name!r} has edges of different durations: build it with a time step dt")
        caps = capabilities or ["fly+drive"] * len(starts)
        return cls(
            dt=dt,
            starts=np.array([graph.index[s] for s in starts], dtype=np.int64),
            goals=np.array([graph.index[g] for g in goals], dtype=np.int64),
            move_cost=graph.edge_cost(mu),
            wait_cost=graph.wait_cost_rate(mu) * dt,
            move_charge=graph.charge,
            wait_charge=graph.wait_charge_rate() * dt,
            usable=np.array(usable if usable is not None else [graph.model.usable_ah] * len(starts), dtype=float),
            allowed=np.array([graph.allowed_edges(c) for c in caps], dtype=bool).reshape(len(starts), graph.n_edges),
        )

    def per_vehicle(self, move: np.ndarray) -> np.ndarray:
        """(V, E): an edge weight for each vehicle, infinite on the edges it may not take."""
        return np.where(self.allowed, move[None, :], np.inf)


@dataclass(frozen=True)
class EdgeGroups:
    """The edges grouped by one endpoint (`nodes`), with the other endpoint of each: the least over
    a node's incoming (or outgoing) edges becomes one np.minimum.reduceat."""

    order: np.ndarray  # edge ids sorted by the grouping endpoint
    other: np.ndarray  # the opposite endpoint of each edge in `order`
    nodes: np.ndarray  # the distinct grouping endpoints
    starts: np.ndarray  # where each group begins in `order`

    @classmethod
    def by(cls, key: np.ndarray, other: np.ndarray) -> EdgeGroups:
        order = np.argsort(key, kind="stable")
        nodes, starts = np.unique(key[order], return_index=True)
        return cls(order, other[order], nodes, starts)

    def relax(self, values: np.ndarray, weight: np.ndarray, into: np.ndarray) -> None:
        """into[:, n] = min(into[:, n], min over the group's edges of values[:, other] + weight); the
        weight per edge (E,) or per vehicle and edge (V, E)."""
        if not len(self.order):
            return
        best = np.minimum.reduceat(values[:, self.other] + weight[..., self.order], self.starts, axis=1)
        into[:, self.nodes] = np.minimum(into[:, self.nodes], best)


def edge_groups(graph: FleetGraph) -> tuple[EdgeGroups, EdgeGroups]:
    """Edges grouped by head (for forward passes) and by tail (backward), once per graph."""
    tail, head = graph.edges[:, 0], graph.edges[:, 1]
    return per_graph(graph, "ilp_edge_groups", lambda: (EdgeGroups.by(head, tail), EdgeGroups.by(tail, head)))


def _step_forward(f: np.ndarray, into_heads: EdgeGroups, move: np.ndarray, wait: np.ndarray) -> np.ndarray:
    nxt = f + wait
    into_heads.relax(f, move, nxt)
    return nxt


def least_forward(graph: FleetGraph, starts: np.ndarray, move: np.ndarray, wait: np.ndarray, steps: int) -> np.ndarray:
    """F (steps+1, V, N): least weight to be at node n at time k, moving (`move` per edge) and
    waiting (`wait` per node and step)."""
    into_heads, _ = edge_groups(graph)
    f = np.full((steps + 1, len(starts), graph.n_nodes), np.inf)
    f[0, np.arange(len(starts)), starts] = 0.0
    for k in range(steps):
        f[k + 1] = _step_forward(f[k], into_heads, move, wait)
    return f


def least_backward(graph: FleetGraph, goals: np.ndarray, move: np.ndarray, steps: int) -> np.ndarray:
    """B (steps+1, V, N): least weight from node n to the goal within r steps (arriving early is
    free, and waiting first never helps)."""
    _, from_tails = edge_groups(graph)
    b = np.full((steps + 1, len(goals), graph.n_nodes), np.inf)
    b[0, np.arange(len(goals)), goals] = 0.0
    for r in range(steps):
        b[r + 1] = b[r]
        from_tails.relax(b[r], move, b[r + 1])
    return b


def battery_horizons(graph: FleetGraph, fleet: Fleet) -> tuple[np.ndarray, np.ndarray]:
    """Per vehicle the fewest steps to its goal within its battery (-1 if none) and the least charge
    to its goal over the steps explored: all N - 1 that a least-charge route (no waits, no repeated
    node) may need, for a vehicle that never fits."""
    into_heads, _ = edge_groups(graph)
    vehicles = np.arange(len(fleet.starts))
    f = np.full((len(fleet.starts), graph.n_nodes), np.inf)
    f[vehicles, fleet.starts] = 0.0
    least = f[vehicles, fleet.goals]
    fewest = np.where(least <= fleet.usable * (1 + TOL), 0, -1)
    for k in range(1, graph.n_nodes):
        if (fewest >= 0).all():
            break
        f = _step_forward(f, into_heads, fleet.per_vehicle(fleet.move_charge), fleet.wait_charge)
        at_goal = f[vehicles, fleet.goals]
        fewest = np.where((fewest < 0) & (at_goal <= fleet.usable * (1 + TOL)), k, fewest)
        least = np.minimum(least, at_goal)
    return fewest, least


MOVE, WAIT, STAY = 0, 1, 2


@dataclass(frozen=True)
class Columns:
    """One binary variable per (vehicle, arc, step). `kind` MOVE, WAIT or STAY (finish or stay at
    g*); `ptype` the physical arc type of ilp_arcs (goal-stay arcs are waits at the goal); tail/head
    are network nodes (N stands for the vehicle's g*)."""

    veh: np.ndarray
    step: np.ndarray
    kind: np.ndarray
    ptype: np.ndarray
    tail: np.ndarray
    head: np.ndarray
    cost: np.ndarray
    charge: np.ndarray

    def __len__(self) -> int:
        return len(self.veh)

    def subset(self, keep: np.ndarray) -> Columns:
        return Columns(*(getattr(self, f.name)[keep] for f in fields(self)))


def _concat(parts: list[tuple]) -> Columns:
    return Columns(*(np.concatenate(f) for f in zip(*parts, strict=True)))


def _arc_weights(graph: FleetGraph, fleet: Fleet, horizon: int, move: np.ndarray, wait: np.ndarray):
    """Per vehicle: F[k] + w + B[T-k-1] over move arcs (T, V, E) and wait arcs (T, V, N), and F at
    each goal (T, V)."""
    t = horizon
    f = least_forward(graph, fleet.starts, move, wait, t)[:t]
    rest = least_backward(graph, fleet.goals, move, t)[t - 1 - np.arange(t)]  # B[T-k-1]
    tail, head = graph.edges[:, 0], graph.edges[:, 1]
    return f[:, :, tail] + move + rest[:, :, head], f + wait + rest, f[:, np.arange(len(fleet.goals)), fleet.goals]


def vehicle_columns(graph: FleetGraph, fleet: Fleet, horizon: int) -> Columns:
    """The arcs of every vehicle for a horizon of `horizon` steps that fit its battery."""
    n_n, n_e, t = graph.n_nodes, graph.n_edges, horizon
    budget = fleet.usable * (1 + TOL)
    moves, waits, at_goal = _arc_weights(graph, fleet, t, fleet.per_vehicle(fleet.move_charge), fleet.wait_charge)
    tail, head = graph.edges[:, 0], graph.edges[:, 1]
    steps = np.arange(t)
    parts: list[tuple] = []
    for i, g in enumerate(fleet.goals):
        k, e = np.nonzero(moves[:, i] <= budget[i])
        parts.append((np.full(len(k), i), k, np.full(len(k), MOVE), e, tail[e], head[e],
                      fleet.move_cost[e], fleet.move_charge[e]))
        k, n = np.nonzero(waits[:, i] <= budget[i])
        parts.append((np.full(len(k), i), k, np.full(len(k), WAIT), n_e + n, n, n,
                      fleet.wait_cost[n], fleet.wait_charge[n]))
        finish = np.flatnonzero(at_goal[:, i] <= budget[i])
        stay = steps[steps > finish[0]] if len(finish) else steps[:0]
        k = np.concatenate([finish, stay])
        parts.append((np.full(len(k), i), k, np.full(len(k), STAY), np.full(len(k), n_e + g),
                      np.concatenate([np.full(len(finish), g), np.full(len(stay), n_n)]), np.full(len(k), n_n),
                      np.zeros(len(k)), np.zeros(len(k))))
    return _concat(parts)


def least_costs(graph: FleetGraph, fleet: Fleet, horizon: int) -> np.ndarray:
    """Per vehicle the least eq. 3 cost to its goal within the horizon, ignoring the others."""
    b = least_backward(graph, fleet.goals, fleet.per_vehicle(fleet.move_cost), horizon)[horizon]
    return b[np.arange(len(fleet.starts)), fleet.starts]


def within_cost(graph: FleetGraph, fleet: Fleet, cols: Columns, horizon: int, upper: float) -> np.ndarray:
    """Mask of the columns some plan of cost <= `upper` may use (see the module docstring)."""
    moves, waits, at_goal = _arc_weights(graph, fleet, horizon, fleet.per_vehicle(fleet.move_cost), fleet.wait_cost)
    own = least_costs(graph, fleet, horizon)
    slack = upper * (1 + TOL) - (own.sum() - own)  # (V,) what vehicle i may spend
    n_e = graph.n_edges
    need = np.empty(len(cols))
    kind, veh, step = cols.kind, cols.veh, cols.step
    m = kind == MOVE
    need[m] = moves[step[m], veh[m], cols.ptype[m]]
    w = kind == WAIT
    need[w] = waits[step[w], veh[w], cols.ptype[w] - n_e]
    s = kind == STAY
    arrived = np.minimum.accumulate(at_goal, axis=0)  # least cost to have arrived by step k
    need[s] = np.where(cols.tail[s] < graph.n_nodes, at_goal[step[s], veh[s]], arrived[step[s] - 1, veh[s]])
    return need <= slack[veh]



def _keys(cols: Columns, horizon: int, n_nodes: int, n_edges: int) -> np.ndarray:
    """A unique key per column: (vehicle, step, arc type, kind, leaves g*): a wait at the goal, the
    finish arc and a stay share the arc type."""
    from_star = (cols.tail == n_nodes).astype(np.int64)
    return (((cols.veh * horizon + cols.step) * (n_edges + n_nodes) + cols.ptype) * 3 + cols.kind) * 2 + from_star


def carry_over(old: Columns, chosen: np.ndarray, new: Columns, new_horizon: int, goals: np.ndarray,
               n_nodes: int, n_edges: int) -> np.ndarray | None:
    """Indices in `new` (a longer horizon) of the plan `chosen` among `old`, extended by staying at
    the goals (a plan for T is one for T + k at the same cost); None if `new` lacks one of its arcs."""
    plan = old.subset(chosen)
    old_horizon = int(plan.step.max()) + 1
    arrived = np.zeros(len(goals), dtype=bool)  # at g* when the old horizon ends
    last = plan.step == old_horizon - 1
    arrived[plan.veh[last]] = plan.head[last] == n_nodes
    v = np.repeat(np.arange(len(goals)), new_horizon - old_horizon)
    k = np.tile(np.arange(old_horizon, new_horizon), len(goals))
    from_star = arrived[v] | (k > old_horizon)  # else the finish arc g -> g* comes first
    zeros = np.zeros(len(v))
    stays = Columns(v, k, np.full(len(v), STAY), n_edges + goals[v], np.where(from_star, n_nodes, goals[v]),
                    np.full(len(v), n_nodes), zeros, zeros)
    wanted = np.concatenate([_keys(plan, new_horizon, n_nodes, n_edges), _keys(stays, new_horizon, n_nodes, n_edges)])
    have = _keys(new, new_horizon, n_nodes, n_edges)
    order = np.argsort(have)
    at = order[np.minimum(np.searchsorted(have, wanted, sorter=order), len(have) - 1)]
    return np.sort(at) if np.array_equal(have[at], wanted) else None
