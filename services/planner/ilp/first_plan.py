"""A first plan inside the ILP's own network: prioritized planning (paper 000 §V-D) in discrete time.

Vehicles are planned one at a time, cheapest-first search over their columns (ilp_network) for the
least eq. 3 cost, avoiding every arc that collides (ilp_arcs `touch`) with an arc claimed by an
earlier vehicle in the same step. On well-formed maps the vehicles not planned yet claim their
parked bodies at their start and goal for the whole horizon (revised prioritized planning, Čáp et
al. 2015), so later vehicles can still leave and arrive; but a spot that is one vehicle's start and
another's goal is not claimed (else a cycle of such vehicles could never be planned): whichever is
planned second must then leave before, or arrive after, the other. The plan is a MIP start for HiGHS and its
cost an upper bound for pruning (ilp_network.within_cost); it may not exist within a short horizon.
"""

from __future__ import annotations

import numpy as np

from services.planner.ilp.arcs import ArcTable
from services.planner.ilp.network import Columns, Fleet


class Claims:
    """How many claimed arcs each arc type collides with, per step."""

    def __init__(self, table: ArcTable, horizon: int) -> None:
        self.table = table
        self.count = np.zeros((horizon, len(table.tail)), dtype=np.int32)

    def add(self, steps: np.ndarray, ptypes: np.ndarray, sign: int = 1) -> None:
        ptr, ids = self.table.touch_ptr, self.table.touch_ids
        counts = ptr[ptypes + 1] - ptr[ptypes]
        first = np.repeat(ptr[ptypes], counts)
        offsets = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
        np.add.at(self.count, (np.repeat(steps, counts), ids[first + offsets]), sign)

    def park(self, node: int, sign: int) -> None:
        """A body parked at `node` for the whole horizon (wait arcs are types E + n)."""
        horizon = len(self.count)
        self.add(np.arange(horizon), np.full(horizon, self.table.n_edges + node), sign)


def cheapest_path(cols: Columns, mine: np.ndarray, bounds: np.ndarray, claims: Claims, start: int, goal: int,
                  n_nodes: int) -> np.ndarray | None:
    """Column indices of one vehicle's cheapest unclaimed path (by step), or None. `mine` holds its
    columns sorted by step, `bounds[k]:bounds[k+1]` those of step k."""
    horizon = len(bounds) - 1
    best = np.full((horizon + 1, n_nodes + 1), np.inf)
    pred = np.full((horizon + 1, n_nodes + 1), -1, dtype=np.int64)
    best[0, start] = 0.0
    for k in range(horizon):
        j = mine[bounds[k]:bounds[k + 1]]
        j = j[claims.count[k, cols.ptype[j]] == 0]
        cand = best[k, cols.tail[j]] + cols.cost[j]
        ok = np.isfinite(cand)
        j, cand = j[ok], cand[ok]
        order = np.lexsort((cand, cols.head[j]))
        heads, first = np.unique(cols.head[j][order], return_index=True)
        best[k + 1, heads] = cand[order][first]
        pred[k + 1, heads] = j[order][first]
    node = goal if best[horizon, goal] <= best[horizon, n_nodes] else n_nodes
    if not np.isfinite(best[horizon, node]):
        return None
    path = np.empty(horizon, dtype=np.int64)
    for k in range(horizon, 0, -1):
        path[k - 1] = pred[k, node]
        node = cols.tail[path[k - 1]]
    return path


def prioritized(cols: Columns, table: ArcTable, fleet: Fleet, horizon: int, n_nodes: int, order: list[int],
                park: bool) -> np.ndarray | None:
    """Indices of the chosen columns of a collision-free plan, vehicles planned in `order`, or None."""
    n_veh = len(fleet.starts)
    by_step = np.lexsort((cols.step, cols.veh))
    keys = cols.veh[by_step] * horizon + cols.step[by_step]
    bounds = np.searchsorted(keys, np.arange(n_veh * horizon + 1))
    claims = Claims(table, horizon)
    shared = set(fleet.starts.tolist()) & set(fleet.goals.tolist())
    spots = [[int(n) for n in (fleet.starts[i], fleet.goals[i]) if park and n not in shared] for i in range(n_veh)]
    for own in spots:
        for node in own:
            claims.park(node, 1)
    chosen: list[np.ndarray] = []
    for i in order:
        for node in spots[i]:
            claims.park(node, -1)
        path = cheapest_path(cols, by_step, bounds[i * horizon:(i + 1) * horizon + 1], claims,
                             int(fleet.starts[i]), int(fleet.goals[i]), n_nodes)
        if path is None:
            return None
        claims.add(cols.step[path], cols.ptype[path])
        chosen.append(path)
    return np.sort(np.concatenate(chosen))

