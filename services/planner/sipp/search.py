"""Single-vehicle multimodal SIPP (paper 000 §V-D, Alg. 1 and 2) in continuous time.

A state is a node with one of its safe intervals. Waiting happens inside a safe interval, so a
successor (Alg. 2) is, for each out-edge (u, v) and each safe interval of v reachable from the current
one, the earliest arrival: the earliest departure tau >= t that keeps u safe until tau, is a free
departure time of the edge, and lands in the interval. Earliest is also cheapest from a given
arrival: waiting only adds cost. Each state keeps two arrivals, the earliest and the cheapest (the
paper's compromise, Alg. 1 lines 14-18): an arrival enters OPEN when it improves either, and a
popped arrival that is neither any more is dropped. The cost of an arrival is eq. 3 per traversal
plus the wait rate times the wait (hovering costs fly power); its charge (eq. 4-5) is tracked alike,
and arrivals whose charge plus the least charge-to-go exceed the usable charge are pruned (§V-C).
A path may enter a parking spot or helipad only as its goal (Alg. 2 line 10), and the goal counts
only in a safe interval that never ends: the vehicle stays there forever.
"""

from __future__ import annotations

import heapq
import math
import time
from bisect import bisect_left
from dataclasses import dataclass
from typing import NamedTuple

from common.domain.vehicle_model import Capabilities
from services.planner.graph.fleet_graph import FleetGraph
from services.planner.graph.memo import per_graph
from services.planner.sipp.heuristic import spot_mask
from services.planner.sipp.safe_intervals import Reservations
from services.planner.sipp.turns import edge_headings, turn_time

INF = math.inf
DEADLINE_EVERY = 512  # expansions between clock checks


class TimedPath(NamedTuple):
    """nodes[i] reached at arrive[i] and left at depart[i] (inf at the goal) along edges[i]."""

    nodes: list[int]
    arrive: list[float]
    depart: list[float]
    edges: list[int]
    cost: float
    charge: float


@dataclass(frozen=True)
class SearchGraph:
    """Adjacency for one mu: out[u] = [(edge, head, duration, eq. 3 cost, charge)], per-node wait
    cost and charge rates (per second), which nodes may be passed through, and for the turns at
    corners (`turns.py`) each edge's heading and the rate turns are budgeted at."""

    out: list[list[tuple[int, int, float, float, float]]]
    wait_cost: list[float]
    wait_charge: list[float]
    passable: list[bool]
    heading: list[float]
    turn_rate: float

    @staticmethod
    def of(graph: FleetGraph, mu: float, capabilities: Capabilities = "fly+drive") -> SearchGraph:
        """The adjacency of the edges a vehicle with `capabilities` may take."""
        return per_graph(graph, ("search_graph", float(mu), capabilities),
                         lambda: _build_search_graph(graph, mu, capabilities))


def _build_search_graph(graph: FleetGraph, mu: float, capabilities: Capabilities) -> SearchGraph:
    cost = graph.edge_cost(mu).tolist()
    charge = graph.charge.tolist()
    dur = graph.duration.tolist()
    heads = graph.edges[:, 1].tolist()
    ok = graph.allowed_edges(capabilities).tolist()
    out = [[(e, heads[e], dur[e], cost[e], charge[e]) for e in graph.out_edges[u].tolist() if ok[e]]
           for u in range(graph.n_nodes)]
    return SearchGraph(
        out=out,
        wait_cost=graph.wait_cost_rate(mu).tolist(),
        wait_charge=graph.wait_charge_rate().tolist(),
        passable=(~spot_mask(graph)).tolist(),
        heading=edge_headings(graph),
        turn_rate=graph.model.speed.turn,
    )


class SearchTimeout(Exception):
    """The deadline passed during a search."""


def sipp(
    sg: SearchGraph,
    res: Reservations,
    start: int,
    goal: int,
    h: list[float],
    q_to_go: list[float],
    usable_ah: float,
    deadline: float,
    t_start: float = 0.0,
) -> TimedPath | None:
    """Alg. 1: the path found for one vehicle from `start` (at time `t_start`) to rest at `goal`
    forever, or None when none exists under the reservations and the battery. Raises SearchTimeout."""
    node_s, node_e = res.node_start, res.node_end
    edge_s, edge_e = res.edge_start, res.edge_end
    closed_n, closed_e = res.node_closed, res.edge_closed
    out, wait_cost, wait_charge, passable = sg.out, sg.wait_cost, sg.wait_charge, sg.passable
    heading, turn_rate = sg.heading, sg.turn_rate
    n_nodes = len(out)

    k0 = res.interval_at(start, t_start)
    if k0 is None or h[start] == INF:
        return None
    if not node_e[goal] or node_e[goal][-1] != INF or closed_n[goal]:
        return None  # the goal is never free for ever: no search (it would exhaust every interval)
    # arrivals: node, state key, end of its safe interval, time, cost, charge, parent arrival,
    # departure from the parent's node, edge from the parent
    a_node = [start]
    a_key = [k0 * n_nodes + start]
    a_end = [node_e[start][k0]]
    a_t = [t_start]
    a_c = [0.0]
    a_q = [0.0]
    a_parent = [-1]
    a_dep = [t_start]
    a_edge = [-1]
    # per state: [earliest (t, c, arrival id), cheapest (c, t, arrival id)]
    best: dict[int, list] = {a_key[0]: [t_start, 0.0, 0, 0.0, t_start, 0]}
    heap: list[tuple[float, float, float, int]] = [(h[start], h[start], t_start, 0)]
    pops = 0
    while heap:
        _, _, t, aid = heapq.heappop(heap)
        rec = best[a_key[aid]]
        if rec[2] != aid and rec[5] != aid:
            continue  # superseded (Alg. 1 line 18)
        u = a_node[aid]
        end_u = a_end[aid]
        if u == goal and end_u == INF:
            return _backtrack(aid, a_node, a_t, a_c, a_q, a_parent, a_dep, a_edge)
        pops += 1
        if pops % DEADLINE_EVERY == 0 and time.perf_counter() > deadline:
            raise SearchTimeout
        c, q = a_c[aid], a_q[aid]
        wc, wq = wait_cost[u], wait_charge[u]
        arrived_along = heading[a_edge[aid]] if turn_rate and a_edge[aid] >= 0 else math.nan
        for e, v, d, ce, qe in out[u]:
            if closed_e[e] or closed_n[v] or not (passable[v] or v == goal):
                continue
            hv = h[v]
            if hv == INF:
                continue
            sv, ev = node_s[v], node_e[v]
            es, ee = edge_s[e], edge_e[e]
            if not ev or not ee:
                continue  # closed for ever, from time 0 (a body at rest there all along)
            ready = t + turn_time(arrived_along, heading[e], turn_rate) if turn_rate else t  # turned onto e
            # first safe interval of v ending at or after the earliest arrival
            j = 0 if ev[0] >= ready + d else bisect_left(ev, ready + d)
            n_v = len(sv)
            while j < n_v:
                tau = sv[j] - d
                if tau < ready:
                    tau = ready
                if tau > end_u:
                    break
                # first free departure interval ending at or after tau
                i = 0 if ee[0] >= tau else bisect_left(ee, tau)
                if i == len(ee):
                    break
                if es[i] > tau:
                    tau = es[i]
                    if tau > end_u:
                        break
                arr = tau + d
                if arr > ev[j]:
                    j = bisect_left(ev, arr, j + 1)
                    continue
                wait = tau - t
                q2 = q + wq * wait + qe
                if q2 + q_to_go[v] > usable_ah:
                    break  # later departures only wait longer
                c2 = c + wc * wait + ce
                skey = j * n_nodes + v
                rec = best.get(skey)
                if rec is None:
                    nid = len(a_node)
                    best[skey] = [arr, c2, nid, c2, arr, nid]
                else:
                    new_t = arr < rec[0] or (arr == rec[0] and c2 < rec[1])
                    new_c = c2 < rec[3] or (c2 == rec[3] and arr < rec[4])
                    if not (new_t or new_c):
                        j += 1
                        continue
                    nid = len(a_node)
                    if new_t:
                        rec[0:3] = arr, c2, nid
                    if new_c:
                        rec[3:6] = c2, arr, nid
                a_node.append(v)
                a_key.append(skey)
                a_end.append(ev[j])
                a_t.append(arr)
                a_c.append(c2)
                a_q.append(q2)
                a_parent.append(aid)
                a_dep.append(tau)
                a_edge.append(e)
                heapq.heappush(heap, (c2 + hv, hv, arr, nid))
                j += 1
    return None


def _backtrack(
    aid: int,
    a_node: list[int],
    a_t: list[float],
    a_c: list[float],
    a_q: list[float],
    a_parent: list[int],
    a_dep: list[float],
    a_edge: list[int],
) -> TimedPath:
    """Alg. 1 line 19: recover the path from the goal arrival."""
    chain = []
    x = aid
    while x >= 0:
        chain.append(x)
        x = a_parent[x]
    chain.reverse()
    nodes = [a_node[x] for x in chain]
    arrive = [a_t[x] for x in chain]
    depart = [a_dep[x] for x in chain[1:]] + [INF]
    edges = [a_edge[x] for x in chain[1:]]
    return TimedPath(nodes, arrive, depart, edges, a_c[aid], a_q[aid])
