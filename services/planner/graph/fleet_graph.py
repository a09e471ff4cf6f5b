"""Map -> 3D graph (paper 000 §V-A, Fig. 2): roads, parking, helipads, air layers, interface nodes.

Nodes: parking, land (road), waypoint (subdivisions), air (layer grid and interface nodes), helipad.
Edges: drive, takeoff, fly, land, each with length, duration, energy (eq. 1-2), charge (eq. 4-5);
costs (eq. 3) for a given mu come from `FleetGraph.edge_cost`, normalised by the largest edge energy
W_max and duration t_max *at the vehicle's speeds* (the plan file's `w_max`, `t_max`).

The one-time-step graph of the ILP (§V-E, built with `dt`). The paper "add[s] waypoint nodes between
the existing ground nodes so that the time it takes to move between nodes takes about 1 timestep" and
"space[s] out the aerial nodes so that the time it takes to travel between nodes takes about 1
timestep"; the planner then assumes exactly one step per edge. Here:
- the air grid of each layer is laid out with spacing max(spacing, v_fly dt) instead of the map's
  `spacing`, so a straight fly edge takes one step at fly speed (an `AirRegion.spacing` coarser than
  that is kept and its edges split like any other);
- then every edge of nominal duration d = length / v_kind is split by waypoint nodes into
  n = ceil(d / dt) equal pieces (d / dt within 1e-6 of an integer counts as that integer).
Rounding rule: up, so a piece, traversed linearly in exactly dt, is never faster than its kind's
speed (DESIGN.md); its slow-down is 1 - d / (n dt): below 1/2 for an edge longer than a step, and
1 - d / dt for one shorter than a step, which is where the largest deviations are (parking access,
short interface edges, layer-to-layer edges, diagonals of the air grid: sqrt 2 steps -> 2 pieces,
29 %). `FleetGraph.slowdown()` measures it; on the shipped maps (maps/README.md) fig6's time-step
graph has none (its geometry is laid out on the step), town's and city934's are listed there.
Edges of the time-step graph keep their duration dt and the energy and charge of traversing in dt
(what the plan will do, what the validator prices); W_max and t_max stay at the vehicle's speeds,
like the base graph's, so an independent checker can recompute them from the plan file alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import networkx as nx
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from common.domain.geometry import bodies_touch, segment_hits_body, touches_keep_out
from common.domain.mapfile import MapSpec
from common.domain.planfile import GraphNode, PlanGraph, PlanModel
from common.domain.vehicle_model import (
    CAPABLE_EDGES,
    EDGE_KINDS,
    Capabilities,
    CostScale,
    EdgeKind,
    NodeKind,
    VehicleModel,
)
from common.errors import InputError
from services.planner.graph.conflicts import Conflicts, compute_conflicts


@dataclass
class FleetGraph:
    """The planners' view: a networkx DiGraph plus numpy arrays for hot loops."""

    name: str
    model: VehicleModel
    g: nx.DiGraph
    dt: float | None
    ids: list[str]
    index: dict[str, int]
    pos: np.ndarray  # (N, 3)
    kinds: list[NodeKind]
    airborne: np.ndarray  # (N,) bool: waiting here means hovering
    edges: np.ndarray  # (E, 2) node indices
    edge_kinds: list[EdgeKind]
    length: np.ndarray
    duration: np.ndarray  # s per traversal: length / speed, or dt on the time-step graph
    energy: np.ndarray
    charge: np.ndarray
    scale: CostScale
    out_edges: list[np.ndarray] = field(repr=False)
    edge_index: dict[tuple[int, int], int] = field(repr=False)
    open_endpoints: bool = False  # any ground node may be a start or goal (MovingAI grids)
    nominal: np.ndarray | None = field(default=None, repr=False)  # s per edge at the vehicle's speeds

    def nominal_duration(self) -> np.ndarray:
        """Each edge's duration at its kind's speed (equal to `duration` off the time-step graph)."""
        return self.duration if self.nominal is None else self.nominal

    def slowdown(self) -> np.ndarray:
        """Per edge 1 - nominal / executed duration: how much slower than its kind's speed a traversal
        is (0 everywhere on the base graph; the deviation of the one-time-step graph, §V-E)."""
        return 1.0 - self.nominal_duration() / self.duration

    @property
    def n_nodes(self) -> int:
        return len(self.ids)

    @property
    def n_edges(self) -> int:
        return len(self.edges)

    @cached_property
    def component(self) -> np.ndarray:
        """Strongly connected component id per node: a task is solvable only within one (MovingAI
        grids may have several, with isolated cells; maps' spots must all share one)."""
        n = self.n_nodes
        adj = csr_matrix((np.ones(self.n_edges), (self.edges[:, 0], self.edges[:, 1])), shape=(n, n))
        return connected_components(adj, directed=True, connection="strong")[1]

    def joined(self, a: str, b: str) -> bool:
        """Whether b is reachable from a and a from b."""
        return bool(self.component[self.index[a]] == self.component[self.index[b]])

    @cached_property
    def conflicts(self) -> Conflicts:
        """Node and edge pairs that would bring two bodies into contact (computed on first use)."""
        return compute_conflicts(self.pos, self.edges, self.model.radius, self.model.height)

    def endpoints(self, capabilities: Capabilities = "fly+drive") -> list[str]:
        """Spots where a task may start or end: parking spots and helipads (any ground node on maps
        with open endpoints). A vehicle that only flies takes off from and lands on helipads and
        road nodes (it cannot drive out of a parking spot); one that only drives uses parking spots."""
        if self.open_endpoints:
            allowed: tuple[str, ...] = ("parking", "helipad", "land")
        else:
            allowed = {"fly+drive": ("parking", "helipad"), "fly": ("helipad", "land"), "drive": ("parking",)}[capabilities]
        return [n for n, k in zip(self.ids, self.kinds, strict=True) if k in allowed]

    def allowed_edges(self, capabilities: Capabilities) -> np.ndarray:
        """(E,) mask of the edges a vehicle with `capabilities` may traverse (`CAPABLE_EDGES`)."""
        kinds = CAPABLE_EDGES[capabilities]
        return np.array([k in kinds for k in self.edge_kinds], dtype=bool)

    def edge_cost(self, mu: float) -> np.ndarray:
        """Eq. 3 per edge."""
        return self.scale.cost(mu, self.energy, self.duration)

    def wait_power(self) -> np.ndarray:
        """Power while waiting at each node: hovering or idle on the ground."""
        p = self.model.power
        return np.where(self.airborne, p.fly, p.idle)

    def wait_cost_rate(self, mu: float) -> np.ndarray:
        """Eq. 3 per second of waiting at each node."""
        return self.scale.cost(mu, self.wait_power(), 1.0)

    def wait_charge_rate(self) -> np.ndarray:
        """Eq. 4-5 per second of waiting at each node (Ah/s)."""
        return self.wait_power() / self.model.voltage / 3600.0

    def to_plan_graph(self) -> PlanGraph:
        nodes = {
            n: GraphNode(pos=(float(p[0]), float(p[1]), float(p[2])), kind=k)
            for n, p, k in zip(self.ids, self.pos, self.kinds, strict=True)
        }
        edges = [(self.ids[u], self.ids[v], k) for (u, v), k in zip(self.edges, self.edge_kinds, strict=True)]
        return PlanGraph(nodes=nodes, edges=edges)

    def plan_model(self) -> PlanModel:
        m = self.model
        return PlanModel(
            radius=m.radius, height=m.height, mass=m.mass, speed=m.speed, power=m.power, voltage=m.voltage,
            capacity_ah=m.capacity_ah, reserve_ah=m.reserve_ah, margin=m.margin,
            w_max=self.scale.w_max, t_max=self.scale.t_max,
        )

    def counts(self) -> tuple[dict[str, int], dict[str, int]]:
        nodes = {k: 0 for k in ("parking", "land", "waypoint", "air", "helipad")}
        for k in self.kinds:
            nodes[k] += 1
        edges = {k: 0 for k in EDGE_KINDS}
        for k in self.edge_kinds:
            edges[k] += 1
        return nodes, edges


def equivalent_mu(mu: float, scale: CostScale, on: CostScale) -> float:
    """The eq. 3 weight that, with the normalisers `on`, ranks plans as `mu` does with `scale`.

    Eq. 3 normalises by the graph's largest edge energy and duration, so one mu weighs time against
    energy differently on a map's base graph (t_max: its longest edge) and on its one-time-step
    graph (t_max <= dt). mu' / W'_max : (1 - mu') / t'_max = mu / W_max : (1 - mu) / t_max makes
    the two costs proportional: a planner on `on` given mu' minimises the same objective as one on
    `scale` given mu (Fig. 7 compares SIPP on the base graph with the ILP on its step graph so)."""
    a, b = mu / scale.w_max * on.w_max, (1.0 - mu) / scale.t_max * on.t_max
    return a / (a + b) if a + b > 0 else mu


def airborne_mask(kinds: list[str], edges: list[tuple[int, int, str]], n: int) -> np.ndarray:
    """A node is airborne when it is an air node, or a waypoint with no drive edge (on a takeoff,
    fly or landing edge). The validator uses the same rule on the plan file's graph."""
    on_road = np.zeros(n, dtype=bool)
    for u, v, k in edges:
        if k == "drive":
            on_road[u] = on_road[v] = True
    kinds_arr = np.array(kinds)
    return (kinds_arr == "air") | ((kinds_arr == "waypoint") & ~on_road)


class _GraphBuilder:
    """Accumulates nodes and directed edges, then freezes into a FleetGraph."""

    def __init__(self, spec: MapSpec, source: str, dt: float | None = None) -> None:
        self.spec = spec
        self.source = source
        self.dt = dt
        self.model = spec.vehicle.envelope()  # bodies grown by the tracking margin
        self.ids: list[str] = []
        self.index: dict[str, int] = {}
        self.pos: list[tuple[float, float, float]] = []
        self.kinds: list[NodeKind] = []
        self.edges: dict[tuple[int, int], EdgeKind] = {}

    def node(self, nid: str, xyz: tuple[float, float, float], kind: NodeKind) -> int:
        if nid in self.index:
            return self.index[nid]
        self.index[nid] = len(self.ids)
        self.ids.append(nid)
        self.pos.append(xyz)
        self.kinds.append(kind)
        return self.index[nid]

    def edge(self, u: int, v: int, kind: EdgeKind, both: bool = False) -> None:
        self.edges[(u, v)] = kind
        if both:
            self.edges[(v, u)] = kind

    # -- the ground -------------------------------------------------------------------------------
    def ground(self) -> None:
        roads = self.spec.roads
        for nid, n in roads.nodes.items():
            self.node(nid, (n.x, n.y, 0.0), "land")
        for u, v in roads.two_way:
            self.edge(self.index[u], self.index[v], "drive", both=True)
        for u, v in roads.one_way:
            self.edge(self.index[u], self.index[v], "drive")
        for spot in self.spec.parking:
            s = self.node(spot.id, (spot.x, spot.y, 0.0), "parking")
            self.edge(s, self.index[spot.road], "drive", both=True)
        for pad in self.spec.helipads:
            self.node(pad.id, (pad.x, pad.y, pad.z), "helipad")

    # -- the air ----------------------------------------------------------------------------------
    def blocked(self, pts: np.ndarray) -> np.ndarray:
        """Body centred at each point (N, 3) would touch a no-fly zone or an obstacle."""
        return touches_keep_out(self.spec, pts, self.model.radius, self.model.height)

    def segments_blocked(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Whether a body moving along each segment a[k] -> b[k] would touch a zone or obstacle."""
        a, b = np.atleast_2d(a), np.atleast_2d(b)
        if not len(a):
            return np.zeros(0, dtype=bool)
        steps = max(2, int(np.ceil(np.linalg.norm(b - a, axis=1).max() / (self.model.radius / 2))) + 1)
        frac = np.linspace(0.0, 1.0, steps)
        pts = a[:, None, :] + frac[None, :, None] * (b - a)[:, None, :]
        return self.blocked(pts.reshape(-1, 3)).reshape(len(a), steps).any(axis=1)

    def air_spacing(self) -> float:
        """The air grid's spacing: the map's, or on the time-step graph at least one fly step (§V-E)."""
        air = self.spec.air
        assert air is not None
        if self.dt is None:
            return air.spacing
        return max(air.spacing, self.model.edge_speed("fly") * self.dt)

    def air(self) -> None:
        air = self.spec.air
        if air is None:
            return
        spacing = self.air_spacing()
        xmin, ymin, xmax, ymax = air.bounds
        nx_ = int(math.floor((xmax - xmin) / spacing + 1e-9)) + 1
        ny_ = int(math.floor((ymax - ymin) / spacing + 1e-9)) + 1
        keys = [(li, i, j) for li in range(len(air.layers)) for i in range(nx_) for j in range(ny_)]
        pts = np.array([(xmin + i * spacing, ymin + j * spacing, air.layers[li]) for li, i, j in keys])
        free = ~self.blocked(pts)
        grid: dict[tuple[int, int, int], int] = {
            key: self.node(f"a{key[0]}_{key[1]}_{key[2]}", tuple(p), "air")
            for key, p, ok in zip(keys, pts, free, strict=True)
            if ok
        }
        steps = [(1, 0), (0, 1)] + ([(1, 1), (1, -1)] if air.diagonals else [])
        pairs = [
            (u, grid[key])
            for (li, i, j), u in grid.items()
            for key in [(li, i + di, j + dj) for di, dj in steps] + [(li + 1, i, j)]
            if key in grid
        ]
        self.add_clear_edges(pairs, "fly")
        self.interfaces(grid)

    def add_clear_edges(self, pairs: list[tuple[int, int]], kind: EdgeKind) -> None:
        """Two-way edges for the pairs whose segment keeps the body clear of zones and obstacles."""
        if not pairs:
            return
        pos = np.array(self.pos)
        ends = np.array(pairs)
        for (u, v), bad in zip(pairs, self.segments_blocked(pos[ends[:, 0]], pos[ends[:, 1]]), strict=True):
            if not bad:
                self.edge(u, v, kind, both=True)

    def interfaces(self, grid: dict[tuple[int, int, int], int]) -> None:
        """Interface air nodes join ground and air (§V-A): one above each road node or helipad under
        free airspace, with a takeoff edge up and a landing edge down, and fly edges to the layer."""
        air = self.spec.air
        assert air is not None
        spacing = self.air_spacing()
        xmin, ymin, xmax, ymax = air.bounds
        margin = spacing / 2
        bases = [(nid, "land") for nid in self.spec.roads.nodes] + [(p.id, "helipad") for p in self.spec.helipads]
        for nid, _ in bases:
            base = np.array(self.pos[self.index[nid]])
            x, y, z0 = base
            if not (xmin - margin <= x <= xmax + margin and ymin - margin <= y <= ymax + margin):
                continue
            layer = next((li for li, z in enumerate(air.layers) if z > z0 + self.model.height), None)
            if layer is None:
                continue
            top = np.array([x, y, air.layers[layer]])
            if self.segments_blocked(base, top)[0]:
                continue
            near = [
                (float(np.hypot(*(np.array(self.pos[v][:2]) - (x, y)))), v)
                for (li, _, _), v in grid.items()
                if li == layer
            ]
            near = [(d, v) for d, v in near if d <= spacing * 1.01]
            if not near:
                continue
            dmin, vmin = min(near)
            if dmin < 0.25 * spacing:
                iface = vmin
            else:
                iface = self.node(f"i_{nid}", tuple(top), "air")
                self.add_clear_edges([(iface, v) for _, v in near], "fly")
            b = self.index[nid]
            self.edge(b, iface, "takeoff")
            self.edge(iface, b, "land")

    # -- uniform time steps -----------------------------------------------------------------------
    def subdivide(self, dt: float) -> None:
        """Split every edge into ceil(duration / dt) pieces joined by waypoint nodes (§V-E; the
        rounding rule of the module docstring)."""
        old = dict(self.edges)
        self.edges = {}
        done: set[tuple[int, int]] = set()
        for (u, v), kind in old.items():
            if (u, v) in done:
                continue
            a, b = np.array(self.pos[u]), np.array(self.pos[v])
            length = float(np.linalg.norm(b - a))
            pieces = max(1, math.ceil(self.model.edge_duration(kind, length) / dt - 1e-6))
            back = old.get((v, u))
            chain = [u]
            for k in range(1, pieces):
                p = a + (b - a) * k / pieces
                lo, hi = sorted((self.ids[u], self.ids[v]))
                frac = k / pieces if self.ids[u] == lo else 1 - k / pieces
                chain.append(self.node(f"w_{lo}_{hi}_{frac:.3f}", tuple(p), "waypoint"))
            chain.append(v)
            for s, t in zip(chain, chain[1:], strict=False):
                self.edge(s, t, kind)
                if back is not None:
                    self.edge(t, s, back)
            done.add((u, v))
            done.add((v, u))

    def freeze(self, dt: float | None) -> FleetGraph:
        pos = np.array(self.pos, dtype=float)
        pairs = list(self.edges.items())
        edges = np.array([uv for uv, _ in pairs], dtype=np.int64).reshape(-1, 2)
        kinds: list[EdgeKind] = [k for _, k in pairs]
        vec = pos[edges[:, 1]] - pos[edges[:, 0]] if len(edges) else np.zeros((0, 3))
        length = np.linalg.norm(vec, axis=1)
        nominal = np.array([self.model.edge_duration(k, d) for k, d in zip(kinds, length, strict=True)])
        duration = np.full(len(edges), dt) if dt is not None else nominal
        energy = np.array(
            [self.model.edge_energy(k, d, dz, t) for k, d, dz, t in zip(kinds, length, vec[:, 2], duration, strict=True)]
        )
        at_speed = np.array(
            [self.model.edge_energy(k, d, dz) for k, d, dz in zip(kinds, length, vec[:, 2], strict=True)]
        )
        charge = np.array([self.model.edge_charge(k, t) for k, t in zip(kinds, duration, strict=True)])
        g = nx.DiGraph()
        for i, (nid, k) in enumerate(zip(self.ids, self.kinds, strict=True)):
            g.add_node(nid, pos=tuple(pos[i]), kind=k, index=i)
        for e, ((u, v), k) in enumerate(pairs):
            g.add_edge(self.ids[u], self.ids[v], kind=k, index=e, length=length[e], duration=duration[e])
        out_edges: list[list[int]] = [[] for _ in self.ids]
        for e, (u, _) in enumerate(edges):
            out_edges[u].append(e)
        airborne = airborne_mask(self.kinds, [(int(u), int(v), k) for (u, v), k in zip(edges, kinds, strict=True)], len(self.ids))
        scale = CostScale(w_max=float(at_speed.max(initial=1e-9)), t_max=float(nominal.max(initial=1e-9)))
        return FleetGraph(
            name=self.spec.name, model=self.model, g=g, dt=dt, ids=list(self.ids), index=dict(self.index),
            pos=pos, kinds=list(self.kinds), airborne=airborne, edges=edges, edge_kinds=kinds, length=length,
            duration=duration, energy=energy, charge=charge, scale=scale,
            out_edges=[np.array(o, dtype=np.int64) for o in out_edges],
            edge_index={(int(u), int(v)): e for e, (u, v) in enumerate(edges)},
            nominal=nominal if dt is not None else None,
        )


def build_graph(spec: MapSpec, dt: float | None = None, source: str | None = None, open_endpoints: bool = False) -> FleetGraph:
    """Build the 3D graph of a map; with `dt`, on the uniform-time-step graph (§V-E). With
    `open_endpoints` (MovingAI grids: any ground node may be a start or goal) the graph may have
    several components (isolated cells): tasks are checked to lie within one when they are read."""
    src = source or spec.name
    b = _GraphBuilder(spec, src, dt)
    b.ground()
    check_spots(b, src)
    b.air()
    if dt is not None:
        b.subdivide(dt)
    graph = b.freeze(dt)
    graph.open_endpoints = open_endpoints
    if not open_endpoints:
        check_reachable(graph, src)
    return graph


def check_spots(b: _GraphBuilder, source: str) -> None:
    """Well-formed infrastructure (§V-D): a vehicle on a spot must not touch another spot's vehicle,
    nor a vehicle on any road edge other than its own access edge."""
    r, h = b.model.radius, b.model.height
    spots = [(f"parking[{i}]", s.id) for i, s in enumerate(b.spec.parking)]
    spots += [(f"helipads[{i}]", s.id) for i, s in enumerate(b.spec.helipads)]
    pos = np.array(b.pos)
    for i, (field_i, a) in enumerate(spots):
        pa = pos[b.index[a]]
        for _field_j, c in spots[i + 1:]:
            if bodies_touch(pa - pos[b.index[c]], r, h):
                raise InputError(source, field_i, f"spot {a!r} is too close to spot {c!r} for two bodies of radius {r} m")
        ia = b.index[a]
        road = [(u, v) for (u, v), k in b.edges.items() if k == "drive" and u < v and ia not in (u, v)]
        if road:
            ends = np.array(road)
            lo, hi = segment_hits_body(pos[ends[:, 0]], pos[ends[:, 1]], pa, r, h)
            bad = np.flatnonzero(lo < hi)
            if len(bad):
                u, v = road[bad[0]]
                raise InputError(
                    source, field_i,
                    f"spot {a!r} is too close to road edge {b.ids[u]!r}-{b.ids[v]!r}: a parked body would block it",
                )


def check_reachable(graph: FleetGraph, source: str) -> None:
    """Every spot must reach every other (roads, and through the air where the ground is cut)."""
    spots = graph.endpoints()
    if len(spots) < 2:
        return
    comp = {n: i for i, c in enumerate(nx.strongly_connected_components(graph.g)) for n in c}
    counts: dict[int, int] = {}
    for s in spots:
        counts[comp[s]] = counts.get(comp[s], 0) + 1
    main = max(counts, key=lambda c: counts[c])
    for s in spots:
        if comp[s] != main:
            raise InputError(source, f"parking/helipad {s!r}", "unreachable: no path to and from the other spots")
