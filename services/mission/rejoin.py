"""Bringing a held vehicle back into its running mission (`Replan.rejoin`).

A vehicle that stopped short of another body (the proximity stop), held because another vehicle
was held where its plan goes (the reflex), or stopped on the ground by a fault that may clear (a
stale pose, a lost link) while its plan moved on, or held by the tracking guard late on its plan's
way (not off it), leaves the mission like any held vehicle: the others are replanned around where
it stands. It may come back (its executor says so: `VehicleEvent.rejoinable`), so once it has
stood still, seen, for `REJOIN_AFTER_S` the mission asks the planner to take it back: its old
path, shifted in time so that the path has it where it stands at the replan's switch time
(`progress_at`, `shifted_path`), planned on from its next node like every other vehicle. The
planner refuses while the vehicle's way to its next node crosses a body that left or a vehicle
outside the mission (the one it stopped for may be either): the mission asks again every
`REJOIN_EVERY_S`, `REJOIN_TRIES` times a hold. The plan says it brings the vehicle back
(`VehiclePlan.rejoin`); its executor holds it until the new reference passes where it stands,
then follows it (`VehicleController._take_back`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from common.bus.messages import VehicleState
from common.domain.planfile import PathEntry, Plan, Task

REJOINS = 3
"""How often a vehicle may come back in one mission (one held again and again stays out)."""
REJOIN_AFTER_S = 1.5
"""s a held vehicle stands still before the mission tries to bring it back (its stop settles)."""
REJOIN_EVERY_S = 2.0
"""s between two tries for one vehicle."""
REJOIN_TRIES = 5
"""Tries per hold; then it stays out of the mission (held) until the mission ends."""
REJOIN_WAIT_S = 15.0
"""s after its hold the mission, every other vehicle arrived, still waits for a held vehicle to
come back (one that never stands still is not tried)."""
STILL_MPS = 0.03
"""m/s: the fastest a vehicle that stands still may seem to move (estimation noise)."""
HELD_MODES = frozenset({"holding", "hovering"})


@dataclass
class Candidate:
    """A held vehicle that may come back: the path and task it left with, and its tries so far."""

    path: list[PathEntry]
    task: Task
    since: float
    """When it was held (epoch s)."""
    tries: int = 0
    last_try: float = -math.inf

    def due(self, state: VehicleState | None, now: float) -> bool:
        """Whether to try to bring it back now: standing still where it was held, tries left."""
        return (state is not None and state.mode in HELD_MODES and state.pose_ok
                and math.sqrt(state.vx**2 + state.vy**2 + state.vz**2) < STILL_MPS
                and now - self.since >= REJOIN_AFTER_S and now - self.last_try >= REJOIN_EVERY_S
                and self.tries < REJOIN_TRIES)

    def pending(self, now: float, still_since: float) -> bool:
        """Whether it may still come back (the mission, every other vehicle arrived since
        `still_since`, waits for it): not tried since (nothing moves any more: one more try is
        enough), tries left, within `REJOIN_WAIT_S` of its hold."""
        return self.last_try < still_since and self.tries < REJOIN_TRIES and now - self.since < REJOIN_WAIT_S


def progress_at(plan: Plan, path: list[PathEntry], p: tuple[float, float, float], before: float) -> float:
    """The plan time (s) of the point of `path` nearest to `p`, among the steps begun by `before`
    (where a vehicle held behind its plan stands on it; of points equally near, the latest). In a
    wait the wait's end: the vehicle goes on from there at once."""
    nodes = plan.graph.nodes
    best, best_d = path[0].t, math.inf
    for a, b in zip(path, path[1:], strict=False):
        if a.t > before:
            break
        pa, pb = nodes[a.node].pos, nodes[b.node].pos
        seg = [pb[i] - pa[i] for i in range(3)]
        length2 = sum(c * c for c in seg)
        f = 1.0 if length2 == 0.0 else min(max(sum((p[i] - pa[i]) * seg[i] for i in range(3)) / length2, 0.0), 1.0)
        d = math.dist(p, [pa[i] + f * seg[i] for i in range(3)])
        if d <= best_d + 1e-3:
            best, best_d = a.t + f * (b.t - a.t), min(d, best_d)
    return best


def shifted_path(path: list[PathEntry], progress: float, at: float) -> list[PathEntry]:
    """`path` later by `at - progress`: the point it reached at plan time `progress` at `at`."""
    delay = max(at - progress, 0.0)
    return [PathEntry(e.node, round(e.t + delay, 6)) for e in path]
