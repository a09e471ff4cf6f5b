"""Plan requests the planner could not answer with a plan, kept for replay (`fleet planner
--keep-failed DIR`, `fleet replay-plan FILE`).

A replan of a running fleet is asked from a moment that does not come again: the vehicles' states,
the bodies that left, the previous plan. When one fails (no plan, or a plan the validator refused:
a planner bug), its request is what it takes to see why, and it is gone once the mission moves on.
The service writes each such request (msgpack, with the time limit it was planned with: what was
left of its requester's wait) to DIR/NNN-KIND.msgpack, numbered on from the files already there, up
to `KEEP_MAX` a run; a rejoin refused (`PlanReply.refused`: its mission asks again every few
seconds, as planned) is not kept. `fleet replay-plan` plans it again on any machine with the same
maps. (In an
80-vehicle soak a replan's plan failed validation, two vehicles 0 m apart on a road, once in four
runs; nothing of it was left to look at.) A time-limited plan depends on the CPU it gets: a replan
that failed on a loaded machine may plan on an idle one (replayed, one of an 80-vehicle soak's
0.6 s replans planned in 0.47 s), and a cold planner spends its limit building what a running one
has cached (`warm_up`).
"""

from __future__ import annotations

import logging
from pathlib import Path

import msgspec

from common.bus.messages import PlanReply, PlanRequest
from common.errors import InputError
from services.planner.registry import solve

log = logging.getLogger(__name__)

KEEP_MAX = 50
"""Failed requests kept a run (an 80-vehicle replan is about 0.3 MB)."""


class FailedRequests:
    """Writes failed requests to `folder` (made on the first), numbered after the files already
    there (a planner restarted on the same folder overwrites none), at most `keep_max`."""

    def __init__(self, folder: Path, keep_max: int = KEEP_MAX) -> None:
        self.folder = folder
        self.keep_max = keep_max
        self.kept = 0
        self._last: int | None = None  # the highest number in the folder, once looked at

    def keep(self, req: PlanRequest, reply: PlanReply) -> Path | None:
        """Write `req` if `reply` is a failure worth replaying (not a refused rejoin); its path, or
        None (not kept: a success, a refused rejoin, the limit reached, or the folder not writable)."""
        if reply.ok or reply.refused or self.kept >= self.keep_max:
            return None
        kind = "replan" if req.replan is not None else "plan"
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            if self._last is None:
                self._last = max((int(f.name[:3]) for f in self.folder.glob("[0-9][0-9][0-9]-*.msgpack")), default=0)
            path = self.folder / f"{self._last + 1:03d}-{kind}.msgpack"
            path.write_bytes(msgspec.msgpack.encode(req))
        except OSError as exc:
            log.warning("could not keep a failed plan request in %s: %s", self.folder, exc)
            return None
        self._last += 1
        self.kept += 1
        return path


def read_request(path: Path) -> PlanRequest:
    """A request kept by `FailedRequests`; an `InputError` naming the file if it is not one."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(str(path), "", f"cannot read ({exc.strerror})") from None
    try:
        return msgspec.msgpack.decode(data, type=PlanRequest)
    except msgspec.DecodeError as exc:
        raise InputError(str(path), "", f"not a kept plan request ({exc})") from None


def warm_up(req: PlanRequest) -> None:
    """Plan one vehicle of `req`'s map alone (its first task, or its base plan's): a running planner
    has built the map's graph, its contact pairs, the reservations' footprints and search graph by
    its mission's first plan (about 4 s for city934), which a replay would otherwise spend its
    time limit on."""
    if req.replan is not None:
        base = req.replan.base
        tasks, planner, mu = base.tasks, base.planner, base.mu
    else:
        tasks, planner, mu = req.tasks, req.planner, req.mu
    if tasks:
        vid = min(tasks)
        solve(PlanRequest(map=req.map, tasks={vid: tasks[vid]}, planner=planner, mu=mu, time_limit=30.0))
