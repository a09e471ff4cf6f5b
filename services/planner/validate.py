"""Independent plan checker: `validate_plan(plan)` relies on the plan file alone (DESIGN.md, "Plan file").

What it checks, after paper 000:
- satisfying paths (§IV): every task has a path from its start to its goal, every move follows a
  directed edge of the plan's graph no faster than its kind's speed, time never runs backwards;
- conflict-free trajectories (§IV): the bodies, cylinders of radius r and height h, never intersect at
  any instant of the piecewise-linear motion, counting vehicles parked at their starts before their
  first entry and at their goals after their last, forever;
- the battery (§V-C eq. 4-5): the charge each vehicle draws stays within capacity minus reserve;
- the reported cost (§V-B eq. 1-3): recomputed per traversal and per wait and compared.

Contacts are found analytically. The union of every path's entry times cuts time into global
intervals inside which every vehicle moves linearly, so each pair's relative position is linear too
and its closest approach has a closed form. To keep this fast for large fleets, intervals are grouped
into slabs of SLAB; in each slab a sweep and prune over the bounding boxes of the vehicles' motion
keeps the pairs whose boxes come within reach, and only those are solved exactly, interval by
interval (numpy throughout, no sampling, no per-pair Python loop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from common.domain.geometry import EPS
from common.domain.planfile import PathEntry, Plan, PlanGraph, Task
from common.domain.vehicle_model import CAPABLE_EDGES, CostScale, EdgeKind
from services.planner.graph.fleet_graph import airborne_mask

SPEED_RTOL = 1e-6  # a move may be this much (relative) faster than its edge kind's speed
COST_RTOL, COST_ATOL = 1e-6, 1e-9  # reported vs recomputed cost
CHARGE_RTOL = 1e-9  # float slack on capacity - reserve
MAX_ERRORS = 200  # errors listed in a report; the rest are counted
SEPARATION_HORIZON = 2.0  # min_separation is measured exactly below this many body diameters
SLAB = 16  # global time intervals per pruning slab
POSITION_BUDGET = 1_000_000  # vehicle positions interpolated per batch: bounds memory
ROW_BUDGET = 2_000_000  # (vehicle pair, interval) rows evaluated exactly at once: bounds memory


@dataclass(frozen=True)
class Contact:
    """Two bodies intersecting: `t` is the instant of their smallest horizontal distance (`separation`)
    within one contact episode, with both reference positions at that instant."""

    a: str
    b: str
    t: float
    pos_a: tuple[float, float, float]
    pos_b: tuple[float, float, float]
    separation: float

    def describe(self) -> str:
        pa = ", ".join(f"{x:.3f}" for x in self.pos_a)
        pb = ", ".join(f"{x:.3f}" for x in self.pos_b)
        dz = abs(self.pos_a[2] - self.pos_b[2])
        return (
            f"contact: {self.a} and {self.b} at t={self.t:.3f} s: {self.a} at ({pa}), {self.b} at ({pb}); "
            f"{self.separation:.4f} m apart horizontally, {dz:.4f} m vertically"
        )


@dataclass(frozen=True)
class VehicleStats:
    """One vehicle's path priced with eq. 1-5 up to its last entry.

    arrival_s: the time from which it stays at its final node (the first entry of the trailing run of
    entries at that node); charge_ah: eq. 4-5; energy_j: eq. 1-2 plus wait energy; cost: eq. 3 summed;
    duration_s: the time eq. 3 counts (first to last entry).
    """

    charge_ah: float
    energy_j: float
    cost: float
    arrival_s: float
    duration_s: float = 0.0


@dataclass
class ValidationReport:
    """The verdict on a plan. `ok` iff there are no errors.

    errors: readable messages, at most MAX_ERRORS of them (then one line counting the rest); n_errors
    counts them all. cost / energy: recomputed totals (eq. 3 / J), NaN when some path cannot be priced
    (unknown node, a move off the graph, time running backwards). reported_cost: plan.cost.
    makespan: the latest last entry (s). vehicles: stats of every priceable path. contacts: every
    contact episode. min_separation: the smallest horizontal distance (m) between the reference points
    of two bodies at an instant when they overlap vertically (|dz| < h); the bodies touch iff it is
    below 2r. It is exact when below SEPARATION_HORIZON body diameters (4r) and `inf` otherwise (no
    two bodies ever came that close). unchecked: vehicles whose paths are too malformed to trace,
    left out of the contact check.
    """

    errors: list[str]
    n_errors: int
    cost: float
    reported_cost: float
    energy: float
    makespan: float
    vehicles: dict[str, VehicleStats]
    contacts: list[Contact]
    min_separation: float
    usable_ah: float
    contact_distance: float
    unchecked: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.n_errors == 0

    def cost_on(self, scale: CostScale, mu: float) -> float:
        """The plan's eq. 3 cost recomputed with other normalisers W_max, t_max (and weight mu): eq. 3
        is linear in each traversal's and wait's energy and time, so the total is mu E / W_max +
        (1 - mu) T / t_max over the recomputed energy E and time T. Plans on different graphs of one
        map (SIPP's base graph, the ILP's one-time-step graph, §V-E) compare on one definition this way."""
        if len(self.vehicles) == 0 or math.isnan(self.cost):
            return math.nan
        energy = sum(s.energy_j for s in self.vehicles.values())
        duration = sum(s.duration_s for s in self.vehicles.values())
        return scale.cost(mu, energy, duration)

    @property
    def charge_ah(self) -> dict[str, float]:
        return {v: s.charge_ah for v, s in self.vehicles.items()}

    @property
    def arrival(self) -> dict[str, float]:
        return {v: s.arrival_s for v, s in self.vehicles.items()}

    def summary(self, max_errors: int = 10) -> str:
        """A few lines: verdict, totals, battery, separation, then the first errors."""
        verdict = "valid" if self.ok else f"INVALID ({self.n_errors} error{'s' if self.n_errors != 1 else ''})"
        lines = [
            f"plan: {verdict}",
            f"  {len(self.vehicles)} vehicles priced, makespan {self.makespan:.2f} s, energy {self.energy:.2f} J, "
            f"cost {self.cost:.6f} (reported {self.reported_cost:.6f})",
        ]
        if self.vehicles:
            worst = max(self.vehicles, key=lambda v: self.vehicles[v].charge_ah)
            lines.append(
                f"  battery: most charge used {self.vehicles[worst].charge_ah:.5f} Ah by {worst}, "
                f"usable {self.usable_ah:.5f} Ah"
            )
        sep = "none within 2 diameters" if math.isinf(self.min_separation) else f"{self.min_separation:.4f} m"
        lines.append(
            f"  closest approach (horizontal, while overlapping vertically): {sep}; "
            f"contact below {self.contact_distance:.4f} m; {len(self.contacts)} contact(s)"
        )
        if self.unchecked:
            lines.append(f"  not traced for contacts (malformed paths): {', '.join(self.unchecked)}")
        lines += [f"  - {e}" for e in self.errors[:max_errors]]
        if len(self.errors) > max_errors:
            lines.append(f"  ... {self.n_errors - max_errors} more")
        return "\n".join(lines)


# -- the plan's graph --------------------------------------------------------------------------------


@dataclass
class _Graph:
    """Node positions by id, which nodes are airborne (hovering there costs fly power), edge kinds."""

    pos: dict[str, tuple[float, float, float]]
    airborne: dict[str, bool]
    kind: dict[tuple[str, str], EdgeKind]


def _index_graph(graph: PlanGraph) -> tuple[_Graph, list[str]]:
    """Index the graph; edges naming unknown nodes or listed twice with different kinds are errors."""
    ids = list(graph.nodes)
    index = {n: i for i, n in enumerate(ids)}
    errors: list[str] = []
    kind: dict[tuple[str, str], EdgeKind] = {}
    for u, v, k in graph.edges:
        missing = [n for n in (u, v) if n not in index]
        if missing:
            errors.append(f"graph: edge {u!r}->{v!r} names unknown node {missing[0]!r}")
        elif kind.setdefault((u, v), k) != k:
            errors.append(f"graph: edge {u!r}->{v!r} listed as both {kind[(u, v)]} and {k}")
    indexed = [(index[u], index[v], k) for (u, v), k in kind.items()]
    air = airborne_mask([graph.nodes[n].kind for n in ids], indexed, len(ids))
    pos = {n: graph.nodes[n].pos for n in ids}
    return _Graph(pos=pos, airborne={n: bool(a) for n, a in zip(ids, air, strict=True)}, kind=kind), errors


def _check_model(plan: Plan) -> list[str]:
    """mu in [0, 1] and positive eq. 3 normalisers (the rest of the model is checked on decoding)."""
    errors = []
    if not 0.0 <= plan.mu <= 1.0:
        errors.append(f"mu = {plan.mu} is not in [0, 1]")
    for name in ("w_max", "t_max"):
        value = getattr(plan.model, name)
        if not (math.isfinite(value) and value > 0):
            errors.append(f"model.{name} = {value} must be positive")
    return errors


# -- satisfying paths (§IV) ----------------------------------------------------------------------------


@dataclass
class _PathCheck:
    """errors; traceable: known nodes, finite non-decreasing times (a trajectory is defined);
    priceable: traceable and every move along an edge (eq. 1-5 apply)."""

    errors: list[str]
    traceable: bool
    priceable: bool


def _check_endpoints(vid: str, task: Task, path: list[PathEntry], graph: _Graph) -> list[str]:
    """A satisfying path (§IV) starts at the task's start and ends at its goal, both graph nodes."""
    errors = [f"{vid}: task {end} {n!r} is not a graph node" for end, n in (("start", task.start), ("goal", task.goal)) if n not in graph.pos]
    if path and path[0].node != task.start:
        errors.append(f"{vid}: path starts at {path[0].node!r}, its task starts at {task.start!r}")
    if path and path[-1].node != task.goal:
        errors.append(f"{vid}: path ends at {path[-1].node!r}, its goal is {task.goal!r}")
    return errors


def _check_entries(vid: str, path: list[PathEntry], graph: _Graph) -> list[str]:
    """Every entry names a known node at a finite time."""
    errors = [f"{vid}: entry {i} names unknown node {e.node!r}" for i, e in enumerate(path) if e.node not in graph.pos]
    errors += [f"{vid}: entry {i} has time {e.t}" for i, e in enumerate(path) if not math.isfinite(e.t)]
    return errors


def _check_step(vid: str, i: int, a: PathEntry, b: PathEntry, graph: _Graph, plan: Plan) -> tuple[str | None, bool]:
    """One step a -> b (entries i, i+1): a wait or a move. Returns (error or None, priceable)."""
    tau = b.t - a.t
    if a.node == b.node:
        if tau < 0:
            return f"{vid}: waits a negative time at {a.node!r} (entry {i + 1}: {a.t:.6g} s -> {b.t:.6g} s)", False
        return None, True
    if tau < 0:
        return f"{vid}: time goes backwards from {a.node!r} to {b.node!r} (entry {i + 1}: {a.t:.6g} s -> {b.t:.6g} s)", False
    kind = graph.kind.get((a.node, b.node))
    if kind is None:
        back = " (only the reverse edge exists)" if (b.node, a.node) in graph.kind else ""
        return f"{vid}: jumps from {a.node!r} to {b.node!r} at t={a.t:.6g} s: no such edge{back}", False
    length = math.dist(graph.pos[a.node], graph.pos[b.node])
    speed = plan.model.edge_speed(kind)
    if length > speed * tau * (1.0 + SPEED_RTOL):
        need = length / speed
        return (
            f"{vid}: too fast on {kind} edge {a.node!r}->{b.node!r}: {tau:.6g} s for {length:.4g} m, "
            f"needs at least {need:.6g} s at {speed:g} m/s"
        ), True
    return None, True


def _check_path(vid: str, task: Task | None, path: list[PathEntry], graph: _Graph, plan: Plan) -> _PathCheck:
    """All path rules for one vehicle (task None: a path without a task, checked for shape only)."""
    if not path:
        return _PathCheck([f"{vid}: empty path"], False, False)
    errors = [] if task is None else _check_endpoints(vid, task, path, graph)
    entry_errors = _check_entries(vid, path, graph)
    if entry_errors:
        return _PathCheck(errors + entry_errors, False, False)
    traceable = priceable = True
    allowed = CAPABLE_EDGES[task.capabilities if task is not None else "fly+drive"]
    for i, (a, b) in enumerate(pairwise(path)):
        error, priced = _check_step(vid, i, a, b, graph, plan)
        if error:
            errors.append(error)
        elif a.node != b.node and graph.kind[(a.node, b.node)] not in allowed:
            errors.append(f"{vid}: entry {i + 1}: a {graph.kind[(a.node, b.node)]} edge {a.node} -> {b.node}, "
                          f"but the vehicle's capabilities are {task.capabilities if task else 'fly+drive'}")
        traceable &= b.t >= a.t
        priceable &= priced
    return _PathCheck(errors, traceable, priceable and traceable)


# -- energy, charge and cost (§V-B eq. 1-3, §V-C eq. 4-5) --------------------------------------------------


def _arrival(path: list[PathEntry]) -> float:
    """Start of the trailing run of entries at the final node."""
    k = len(path) - 1
    while k > 0 and path[k - 1].node == path[-1].node:
        k -= 1
    return path[k].t


def _vehicle_stats(path: list[PathEntry], graph: _Graph, plan: Plan) -> VehicleStats:
    """Price a priceable path until its last entry. A traversal of kind k over tau s draws the mode
    power (eq. 1-2 with tau for d / v, which may exceed the nominal duration); a wait draws fly power
    when hovering and idle power on the ground. Charge by eq. 4-5, cost by eq. 3 with the plan's
    W_max and t_max."""
    model, mu = plan.model, plan.mu
    scale = CostScale(w_max=model.w_max, t_max=model.t_max)
    energy = cost = charge = 0.0
    for a, b in pairwise(path):
        tau = b.t - a.t
        if a.node == b.node:
            power = model.wait_power(graph.airborne[a.node])
            work = power * tau
        else:
            kind = graph.kind[(a.node, b.node)]
            pa, pb = graph.pos[a.node], graph.pos[b.node]
            power = model.mode_power(kind)
            work = model.edge_energy(kind, math.dist(pa, pb), pb[2] - pa[2], tau)
        energy += work
        cost += scale.cost(mu, work, tau)
        charge += model.charge_ah(power, tau)
    return VehicleStats(charge_ah=charge, energy_j=energy, cost=cost, arrival_s=_arrival(path),
                        duration_s=path[-1].t - path[0].t)


def _battery_errors(stats: dict[str, VehicleStats], plan: Plan) -> list[str]:
    """§V-C: the charge drawn may not bring the battery below C_low = the reserve (of what each
    vehicle's battery still holds when its task says so: `Task.usable_ah`)."""
    errors = []
    for vid, s in stats.items():
        task = plan.tasks.get(vid)
        usable = task.usable_ah(plan.model) if task is not None else plan.model.usable_ah
        if s.charge_ah > usable * (1.0 + CHARGE_RTOL):
            errors.append(f"{vid}: battery: uses {s.charge_ah:.6f} Ah, more than the usable {usable:.6f} Ah "
                          "(capacity - reserve - charge used)")
    return errors


def _cost_errors(cost: float, reported: float) -> list[str]:
    if abs(cost - reported) <= COST_RTOL * abs(cost) + COST_ATOL:
        return []
    return [f"cost: the plan reports {reported:.9g}, recomputed (eq. 1-3) {cost:.9g}"]


# -- conflict-free trajectories (§IV) -----------------------------------------------------------------------


def closest_horizontal(d0: np.ndarray, d1: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray]:
    """For relative positions moving linearly d(s) = d0 + s (d1 - d0), s in [0, 1] (rows of (N, 3)):
    the s at which the horizontal distance |d_xy| is smallest among the s where the bodies overlap
    vertically (|d_z| < h), and that distance; (0, inf) for rows that never overlap vertically.
    Bodies of radius r touch iff the distance is below 2r (§IV, common.domain.geometry)."""
    dz0, vz = d0[:, 2], d1[:, 2] - d0[:, 2]
    h = height - EPS
    moving = np.abs(vz) > EPS
    with np.errstate(divide="ignore", invalid="ignore"):
        za, zb = (-h - dz0) / vz, (h - dz0) / vz
    level = np.abs(dz0) < h
    lo = np.where(moving, np.maximum(0.0, np.minimum(za, zb)), np.where(level, 0.0, np.inf))
    hi = np.where(moving, np.minimum(1.0, np.maximum(za, zb)), np.where(level, 1.0, -np.inf))
    overlap = lo < hi
    x0, v = d0[:, :2], d1[:, :2] - d0[:, :2]
    a = np.einsum("ij,ij->i", v, v)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_free = np.where(a > EPS * EPS, -np.einsum("ij,ij->i", x0, v) / a, 0.0)
    s = np.where(overlap, np.clip(s_free, np.where(overlap, lo, 0.0), np.where(overlap, hi, 1.0)), 0.0)
    dist = np.linalg.norm(x0 + s[:, None] * v, axis=1)
    return s, np.where(overlap, dist, np.inf)


@dataclass
class _Hits:
    """Rows of (vehicles a < b, global interval k) in contact, and the smallest separation seen."""

    a: np.ndarray
    b: np.ndarray
    k: np.ndarray
    t: np.ndarray
    sep: np.ndarray
    pos_a: np.ndarray
    pos_b: np.ndarray
    min_sep: float


def _positions(times: list[np.ndarray], points: list[np.ndarray], grid: np.ndarray) -> np.ndarray:
    """(n, len(grid), 3) positions: linear between entries, at the first node before the first entry,
    at the last node after the last."""
    out = np.empty((len(times), len(grid), 3))
    for v, (t, p) in enumerate(zip(times, points, strict=True)):
        for c in range(3):
            out[v, :, c] = np.interp(grid, t, p[:, c])
    return out


def _ragged_arange(counts: np.ndarray) -> np.ndarray:
    """0..c-1 for every c in counts, concatenated."""
    return np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)


def _slab_boxes(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounding boxes (n_slabs, n, 3) of each vehicle's motion over each slab of SLAB intervals, and
    each slab's first interval. Linear motion stays within the box of its end points."""
    m = pos.shape[1] - 1
    starts = np.arange(0, m, SLAB)
    ends = np.minimum(starts + SLAB, m)
    lo = np.minimum(np.minimum.reduceat(pos, starts, axis=1), pos[:, ends])
    hi = np.maximum(np.maximum.reduceat(pos, starts, axis=1), pos[:, ends])
    return lo.transpose(1, 0, 2), hi.transpose(1, 0, 2), starts


def _near_pairs(lo: np.ndarray, hi: np.ndarray, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(slab, a, b), a < b, for the boxes (n_slabs, n, 3) of two vehicles within `reach` of each other
    on every axis. Sweep and prune, all slabs at once: boxes are sorted by their low end along the axis
    of widest spread (slab by slab, each slab shifted past the previous one), and each box is paired
    with the boxes that start before its high end plus reach."""
    n_slabs, n, _ = lo.shape
    axis = int(np.argmax(np.ptp(lo, axis=(0, 1))))
    base = lo[..., axis].min()
    shift = (np.arange(n_slabs) * (hi[..., axis].max() - base + reach[axis] + 1.0))[:, None]
    keys = (lo[..., axis] - base + shift).ravel()
    order = np.argsort(keys, kind="stable")
    bound = (hi[..., axis] - base + reach[axis] + shift).ravel()[order]
    counts = np.searchsorted(keys[order], bound, side="left") - np.arange(len(order)) - 1
    first = np.repeat(np.arange(len(order)), counts)
    e1, e2 = order[first], order[first + 1 + _ragged_arange(counts)]
    slab, a, b = e1 // n, e1 % n, e2 % n
    gap = np.maximum(lo[slab, a] - hi[slab, b], lo[slab, b] - hi[slab, a])
    keep = np.all(gap < reach, axis=1)
    return slab[keep], np.minimum(a, b)[keep], np.maximum(a, b)[keep]


def _exact_rows(
    pos: np.ndarray, grid: np.ndarray, k0: int, first: np.ndarray, last: np.ndarray,
    a: np.ndarray, b: np.ndarray, radius: float, height: float,
) -> _Hits:
    """Closest approach of vehicles a[i] and b[i] on each interval first[i] <= k < last[i] of a batch
    (global interval k0 + k); keeps the rows in contact."""
    counts = last - first
    k = np.repeat(first, counts) + _ragged_arange(counts)
    a, b = np.repeat(a, counts), np.repeat(b, counts)
    s, sep = closest_horizontal(pos[a, k] - pos[b, k], pos[a, k + 1] - pos[b, k + 1], height)
    hit = sep < 2 * radius - EPS
    a, b, k, s = a[hit], b[hit], k[hit], s[hit][:, None]
    return _Hits(
        a=a,
        b=b,
        k=k + k0,
        t=grid[k] + s[:, 0] * (grid[k + 1] - grid[k]),
        sep=sep[hit],
        pos_a=pos[a, k] + s * (pos[a, k + 1] - pos[a, k]),
        pos_b=pos[b, k] + s * (pos[b, k + 1] - pos[b, k]),
        min_sep=float(sep.min(initial=np.inf)),
    )


def _sweep_batch(pos: np.ndarray, grid: np.ndarray, k0: int, radius: float, height: float) -> _Hits:
    """Contacts within one batch of global intervals: prune vehicle pairs slab by slab, then the exact
    closest approach on every interval of the remaining (pair, slab)s, ROW_BUDGET rows at a time. A
    pair left out is farther apart than `reach` on some axis throughout the slab."""
    reach = np.array([2 * radius * SEPARATION_HORIZON] * 2 + [height])
    lo, hi, starts = _slab_boxes(pos)
    slab, a, b = _near_pairs(lo, hi, reach)
    first = starts[slab]
    last = np.minimum(first + SLAB, pos.shape[1] - 1)
    step = max(1, ROW_BUDGET // SLAB)
    return _concat([
        _exact_rows(pos, grid, k0, first[i : i + step], last[i : i + step], a[i : i + step], b[i : i + step], radius, height)
        for i in range(0, max(len(slab), 1), step)
    ])


def _episodes(hits: _Hits) -> np.ndarray:
    """Indices of one row per contact episode (a run of consecutive intervals of one pair): the row
    of smallest separation."""
    order = np.lexsort((hits.k, hits.b, hits.a))
    a, b, k = hits.a[order], hits.b[order], hits.k[order]
    new = np.ones(len(order), dtype=bool)
    new[1:] = (a[1:] != a[:-1]) | (b[1:] != b[:-1]) | (k[1:] != k[:-1] + 1)
    episode = np.cumsum(new)
    best = np.lexsort((hits.sep[order], episode))
    first = np.ones(len(best), dtype=bool)
    first[1:] = episode[best][1:] != episode[best][:-1]
    return order[best[first]]


def _concat(parts: list[_Hits]) -> _Hits:
    return _Hits(
        *(np.concatenate([getattr(p, f) for p in parts]) for f in ("a", "b", "k", "t", "sep", "pos_a", "pos_b")),
        min_sep=min(p.min_sep for p in parts),
    )


def find_contacts(
    names: list[str], times: list[np.ndarray], points: list[np.ndarray], radius: float, height: float,
    since: float = -math.inf,
) -> tuple[list[Contact], float]:
    """Every contact episode between the piecewise-linear trajectories (vehicle v at points[v][i] at
    times[v][i], parked before and after) from `since` on, and the min_separation of
    ValidationReport (§IV)."""
    n = len(names)
    if n < 2:
        return [], math.inf
    grid = np.unique(np.concatenate(times))
    if since > -math.inf:
        grid = np.unique(np.append(grid[grid > since], since))
    grid = np.append(grid, grid[-1] + 1.0)  # one interval with everyone parked at their goals
    step = SLAB * max(1, POSITION_BUDGET // (n * SLAB))
    parts = []
    for k0 in range(0, len(grid) - 1, step):
        window = grid[k0 : k0 + step + 1]
        parts.append(_sweep_batch(_positions(times, points, window), window, k0, radius, height))
    hits = _concat(parts)
    contacts = [
        Contact(
            a=names[hits.a[r]], b=names[hits.b[r]], t=float(hits.t[r]),
            pos_a=tuple(map(float, hits.pos_a[r])), pos_b=tuple(map(float, hits.pos_b[r])), separation=float(hits.sep[r]),
        )
        for r in _episodes(hits)
    ]
    horizon = 2 * radius * SEPARATION_HORIZON
    return sorted(contacts, key=lambda c: c.t), hits.min_sep if hits.min_sep < horizon else math.inf


# -- the report ---------------------------------------------------------------------------------------------


def _trace(plan: Plan, graph: _Graph, vids: list[str]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    times = [np.array([e.t for e in plan.paths[v]]) for v in vids]
    points = [np.array([graph.pos[e.node] for e in plan.paths[v]]) for v in vids]
    return times, points


def _truncate(errors: list[str]) -> list[str]:
    if len(errors) <= MAX_ERRORS:
        return errors
    return errors[:MAX_ERRORS] + [f"... and {len(errors) - MAX_ERRORS} more errors"]


def validate_plan(plan: Plan, check_cost: bool = True, since: float = -math.inf) -> ValidationReport:
    """Check a plan against paper 000 §IV (satisfying, conflict-free), §V-C (battery) and §V-B (cost);
    without `check_cost`, the report's cost prices a plan that has none of its own yet. A replan's
    bodies are checked from its switch time (`since`) on: before it is history, flown or not
    (a vehicle that rejoins a mission has a path shifted in time: `Replan.rejoin`)."""
    graph, errors = _index_graph(plan.graph)
    model_errors = _check_model(plan)
    errors += model_errors
    errors += [f"{vid}: has a task but no path" for vid in plan.tasks if vid not in plan.paths]
    errors += [f"{vid}: has a path but no task" for vid in plan.paths if vid not in plan.tasks]
    checks = {vid: _check_path(vid, plan.tasks.get(vid), path, graph, plan) for vid, path in plan.paths.items()}
    for check in checks.values():
        errors += check.errors
    traced = [v for v, c in checks.items() if c.traceable]
    stats = {v: _vehicle_stats(plan.paths[v], graph, plan) for v, c in checks.items() if c.priceable}
    errors += _battery_errors(stats, plan)
    all_priced = len(stats) == len(plan.paths) and not model_errors
    cost = sum(s.cost for s in stats.values()) if all_priced else math.nan
    if all_priced and check_cost:
        errors += _cost_errors(cost, plan.cost)
    contacts, min_sep = find_contacts(traced, *_trace(plan, graph, traced), plan.model.radius, plan.model.height,
                                      since)
    errors += [c.describe() for c in contacts]
    return ValidationReport(
        errors=_truncate(errors),
        n_errors=len(errors),
        cost=cost,
        reported_cost=plan.cost,
        energy=sum(s.energy_j for s in stats.values()) if all_priced else math.nan,
        makespan=max((plan.paths[v][-1].t for v in traced), default=0.0),
        vehicles=stats,
        contacts=contacts,
        min_separation=min_sep,
        usable_ah=plan.model.usable_ah,
        contact_distance=2 * plan.model.radius,
        unchecked=[v for v, c in checks.items() if not c.traceable],
    )
