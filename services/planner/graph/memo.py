"""Per-graph memo of the planners' precomputed tables (SIPP: adjacency lists, footprints, cost-to-go;
the ILP: arc tables, networks).

A FleetGraph is a mutable dataclass (unhashable), and the loader already caches one object per map
file, so tables are keyed by the graph object's identity and dropped when the graph is collected.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

from services.planner.graph.fleet_graph import FleetGraph

T = TypeVar("T")

_MEMO: dict[int, tuple[weakref.ref, dict[Hashable, Any]]] = {}


def per_graph(graph: FleetGraph, key: Hashable, build: Callable[[], T]) -> T:
    """The value of `build()` for (graph, key), computed once while the graph is alive."""
    gid = id(graph)
    entry = _MEMO.get(gid)
    if entry is None or entry[0]() is not graph:
        entry = (weakref.ref(graph, lambda _ref, gid=gid: _MEMO.pop(gid, None)), {})
        _MEMO[gid] = entry
    table = entry[1]
    if key not in table:
        table[key] = build()
    return table[key]
