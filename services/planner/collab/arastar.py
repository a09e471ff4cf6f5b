"""ARA* (Likhachev et al. 2003, 002 ref. [17]) and weighted A* over integer states (002 §IV-B).

ARA* runs weighted A* with a decreasing inflation eps, reusing search effort: states whose g drops
after they were expanded go to the INCONS list and rejoin OPEN at the next eps. Each published
path is within eps' = min(eps, g(goal) / min over OPEN and INCONS of (g + h)) of optimal for an
admissible h. The goal is a set of states (a predicate); weighted A* is a single-eps run.
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

Successors = Callable[[int], list[tuple[int, float]]]
Heuristic = Callable[[int], float]
GoalTest = Callable[[int], bool]


@dataclass
class SearchResult:
    """The best path found (None if none), its cost and proven bound, and the effort spent."""

    path: list[int] | None
    cost: float
    eps: float
    expansions: int
    iterations: int
    first_solution_s: float | None
    elapsed_s: float
    timed_out: bool
    g: dict[int, float] = field(repr=False, default_factory=dict)


def arastar(
    start: int,
    succ: Successors,
    h: Heuristic,
    is_goal: GoalTest,
    eps0: float = 2.0,
    eps_step: float = 0.25,
    eps_final: float = 1.0,
    time_limit: float = math.inf,
    improve_s: float = 0.0,
    max_expansions: int | None = None,
) -> SearchResult:
    """ARA*: a first solution within `time_limit` s (or `max_expansions`), then improvements for up
    to `improve_s` s more, lowering eps by `eps_step` down to `eps_final`."""
    t0 = time.perf_counter()
    deadline = t0 + time_limit
    g: dict[int, float] = {start: 0.0}
    parent: dict[int, tuple[int, float]] = {}
    hval: dict[int, float] = {start: h(start)}
    open_g: dict[int, float] = {start: 0.0}
    closed: set[int] = set()
    incons: set[int] = set()
    best_goal, g_goal = -1, math.inf
    if is_goal(start):
        best_goal, g_goal = start, 0.0
    eps = eps0
    heap: list[tuple[float, float, int]] = [(eps * hval[start], hval[start], start)]
    expansions = iterations = 0
    path: list[int] | None = None
    cost, bound = math.inf, math.inf
    first: float | None = None
    timed_out = False

    def improve() -> bool:
        """Expand until the goal's g is no larger than the least f in OPEN; False on time-out."""
        nonlocal expansions, best_goal, g_goal
        while heap and heap[0][0] < g_goal:
            _, _, s = heapq.heappop(heap)
            gs = open_g.pop(s, None)
            if gs is None or gs != g[s]:
                continue
            closed.add(s)
            expansions += 1
            if expansions & 127 == 0 and (
                time.perf_counter() > deadline or (max_expansions is not None and expansions >= max_expansions)
            ):
                return False
            for t, c in succ(s):
                ng = gs + c
                if ng < g.get(t, math.inf):
                    g[t] = ng
                    parent[t] = (s, c)
                    if t not in hval:
                        hval[t] = h(t)
                    if is_goal(t) and ng < g_goal:
                        best_goal, g_goal = t, ng
                    if t in closed:
                        incons.add(t)
                    else:
                        open_g[t] = ng
                        heapq.heappush(heap, (ng + eps * hval[t], hval[t], t))
        return True

    while True:
        finished = improve()
        if best_goal >= 0 and g_goal < cost and (finished or path is not None):
            # a path found by an unfinished first iteration has no bound yet; later ones improve
            # on a published path, whose bound they inherit
            path, cost = _trace(parent, start, best_goal)
        if not finished:
            timed_out = path is None
            break
        if path is None:
            break  # OPEN exhausted: no path exists
        iterations += 1
        if first is None:
            first = time.perf_counter() - t0
            deadline = t0 + first + improve_s
        lower = min((g[s] + hval[s] for s in (*open_g, *incons)), default=math.inf)
        bound = min(bound, eps, max(1.0, cost / lower) if lower > 0 else eps)
        if bound <= eps_final or time.perf_counter() > deadline:
            break
        eps = max(eps_final, eps - eps_step)
        for s in incons:
            open_g[s] = g[s]
        incons.clear()
        closed.clear()
        heap = [(gs + eps * hval[s], hval[s], s) for s, gs in open_g.items()]
        heapq.heapify(heap)
    return SearchResult(
        path=path,
        cost=cost,
        eps=bound if path is not None else math.inf,
        expansions=expansions,
        iterations=iterations,
        first_solution_s=first,
        elapsed_s=time.perf_counter() - t0,
        timed_out=timed_out,
        g=g,
    )


def weighted_astar(
    start: int,
    succ: Successors,
    h: Heuristic,
    is_goal: GoalTest,
    eps: float,
    time_limit: float = math.inf,
    max_expansions: int | None = None,
) -> SearchResult:
    """Weighted A* (one ARA* iteration at a fixed eps): cost <= eps * optimal for admissible h."""
    return arastar(start, succ, h, is_goal, eps0=eps, eps_final=eps, time_limit=time_limit, max_expansions=max_expansions)


def _trace(parent: dict[int, tuple[int, float]], start: int, goal: int) -> tuple[list[int], float]:
    """The path to `goal` along parent pointers and its cost, which is at most g(goal): a parent
    whose g dropped after it was expanded now leads back along its cheaper path."""
    out, cost = [goal], 0.0
    while out[-1] != start:
        prev, c = parent[out[-1]]
        out.append(prev)
        cost += c
    return out[::-1], cost
