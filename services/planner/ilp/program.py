"""The integer program of paper 000 §V-E (Alg. 3), assembled with numpy into one sparse matrix.

Rows, following Yu & LaValle 2015 §III-A/B and Alg. 3:
- flow conservation (line 4) at every (vehicle, node, time) of the time-expanded network; the
  vehicle's start at time 0 emits one unit, which is the scenario completion (line 5): pruning
  leaves only the goal and g* at the horizon, so the unit must end there;
- meet collisions (line 6) as node capacity: at most one vehicle arrives at a node at a time (this
  also makes arcs that share a tail or a head exclusive, since they meet at that node);
- head-on and all other geometric collisions (line 7): one row per clique of colliding arc types
  (ilp_arcs) and step, "at most one vehicle uses any of these arcs";
- battery (line 8, eq. 6): sum of the arcs' charge <= usable charge, per vehicle;
- objective (line 9, eq. 7): the arcs' eq. 3 cost.
Arc capacity (line 3) is the binaries' upper bound. Collision rows that only one vehicle can enter
are implied by its own flow (one arc per step) and left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import highspy
import numpy as np
from scipy import sparse

from services.planner.ilp.arcs import ArcTable
from services.planner.ilp.network import Columns, Fleet


@dataclass(frozen=True)
class RowBlock:
    """Rows in coordinate form: entry (row, col, value), and the bounds of each row."""

    row: np.ndarray
    col: np.ndarray
    val: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


def _block(keys: np.ndarray, col: np.ndarray, val: np.ndarray, lower: float, upper: float) -> RowBlock:
    """Rows indexed by distinct `keys` (one entry per key occurrence)."""
    uniq, row = np.unique(keys, return_inverse=True)
    return RowBlock(row, col, val, np.full(len(uniq), lower), np.full(len(uniq), upper))


def _shared(keys: np.ndarray, col: np.ndarray, veh: np.ndarray) -> RowBlock:
    """Packing rows `sum <= 1` over entries grouped by key, kept only where two vehicles can meet."""
    uniq, row = np.unique(keys, return_inverse=True)
    width = int(veh.max(initial=0)) + 1
    n_veh = np.bincount(np.unique(row * width + veh) // width, minlength=len(uniq))  # vehicles per row
    keep = n_veh >= 2
    renum = np.cumsum(keep) - 1
    sel = keep[row]
    n = int(keep.sum())
    return RowBlock(renum[row[sel]], col[sel], np.ones(int(sel.sum())), np.zeros(n), np.ones(n))


def flow_rows(cols: Columns, fleet: Fleet, horizon: int, n_nodes: int) -> RowBlock:
    """Conservation: inflow - outflow = 0 at (vehicle, node, k), -1 at the start at time 0."""
    width = n_nodes + 1  # nodes and the vehicle's g*
    j = np.arange(len(cols))
    out_key = (cols.veh * width + cols.tail) * horizon + cols.step
    inner = cols.step + 1 < horizon
    in_key = (cols.veh[inner] * width + cols.head[inner]) * horizon + cols.step[inner] + 1
    source = np.arange(len(fleet.starts)) * width * horizon + fleet.starts * horizon
    keys = np.concatenate([out_key, in_key])
    uniq, row = np.unique(np.concatenate([keys, source]), return_inverse=True)
    bound = np.where(np.isin(uniq, source), -1.0, 0.0)
    n_entries = len(keys)
    return RowBlock(
        row[:n_entries], np.concatenate([j, j[inner]]),
        np.concatenate([-np.ones(len(j)), np.ones(int(inner.sum()))]), bound, bound,
    )


def capacity_rows(cols: Columns, fleet: Fleet, horizon: int, n_nodes: int) -> RowBlock:
    """Meet collisions: at most one vehicle at node n at time k+1 (g* is physically the goal)."""
    phys_head = np.where(cols.head < n_nodes, cols.head, fleet.goals[cols.veh])
    return _shared(phys_head * horizon + cols.step, np.arange(len(cols)), cols.veh)


def clique_rows(cols: Columns, table: ArcTable, horizon: int) -> RowBlock:
    """Head-on and geometric collisions: at most one vehicle on the arcs of a clique in a step."""
    first, last = table.clique_ptr[cols.ptype], table.clique_ptr[cols.ptype + 1]
    counts = last - first
    col = np.repeat(np.arange(len(cols)), counts)
    offsets = np.arange(len(col)) - np.repeat(np.cumsum(counts) - counts, counts)
    clique = table.clique_ids[np.repeat(first, counts) + offsets]
    return _shared(clique * horizon + cols.step[col], col, cols.veh[col])


def battery_rows(cols: Columns, fleet: Fleet, horizon: int) -> RowBlock:
    """Eq. 6 per vehicle, unless the horizon is too short to ever exceed the budget."""
    worst = horizon * max(float(fleet.move_charge.max(initial=0.0)), float(fleet.wait_charge.max(initial=0.0)))
    drawn = (cols.charge > 0) & (worst > fleet.usable[cols.veh])
    veh = cols.veh[drawn]
    rows = _block(veh, np.flatnonzero(drawn), cols.charge[drawn], -highspy.kHighsInf, 0.0)
    rows.upper[:] = fleet.usable[np.unique(veh)]  # one row per vehicle, in vehicle order
    return rows


@dataclass(frozen=True)
class ModelSize:
    """Columns, rows and nonzeros of a model, and its rows per block."""

    columns: int
    rows: int
    nonzeros: int
    flow_rows: int
    capacity_rows: int
    clique_rows: int
    battery_rows: int


def build_lp(cols: Columns, table: ArcTable, fleet: Fleet, horizon: int, n_nodes: int) -> tuple[highspy.HighsLp, ModelSize]:
    """The whole model as a HighsLp with binary columns, minimising eq. 7."""
    blocks = [
        flow_rows(cols, fleet, horizon, n_nodes),
        capacity_rows(cols, fleet, horizon, n_nodes),
        clique_rows(cols, table, horizon),
        battery_rows(cols, fleet, horizon),
    ]
    sizes = [len(b.lower) for b in blocks]
    offsets = np.cumsum([0, *sizes])
    rows = np.concatenate([b.row + o for b, o in zip(blocks, offsets, strict=False)])
    mat = sparse.csc_matrix(
        (np.concatenate([b.val for b in blocks]), (rows, np.concatenate([b.col for b in blocks]))),
        shape=(int(offsets[-1]), len(cols)),
    )
    lp = highspy.HighsLp()
    lp.num_col_ = len(cols)
    lp.num_row_ = int(offsets[-1])
    lp.col_cost_ = cols.cost
    lp.col_lower_ = np.zeros(len(cols))
    lp.col_upper_ = np.ones(len(cols))
    lp.row_lower_ = np.concatenate([b.lower for b in blocks])
    lp.row_upper_ = np.concatenate([b.upper for b in blocks])
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = mat.indptr
    lp.a_matrix_.index_ = mat.indices
    lp.a_matrix_.value_ = mat.data
    lp.integrality_ = [highspy.HighsVarType.kInteger] * len(cols)
    return lp, ModelSize(len(cols), int(offsets[-1]), mat.nnz, *sizes)
