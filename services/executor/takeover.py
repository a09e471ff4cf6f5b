"""Which of the vehicles an executor knows of it owns, and from what it resumes one it takes over.

Ownership is rendezvous hashing over the live executors (`common.domain.ownership`): every executor
and gateway computes the same answer from the same liveliness tokens. When the live set changes,
`reassign` takes the vehicles that now hash to this executor and releases the others; a vehicle
taken over mid-mission resumes from the last state its previous owner published (`resume_from`).
Both of the executor's paths use it: flying cars (`service.py`) and team robots (`team.py`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable

from common.bus.messages import VehicleState
from common.domain.ownership import owner_of

log = logging.getLogger(__name__)


class VehicleOwnership:
    """`take(vid)` and `release(vid)` are the owner's: they build or drop what it runs for a vehicle;
    `held(vid)` says whether it runs one now (a take may be refused, e.g. after a controller failure)."""

    def __init__(self, instance: str, held: Callable[[str], bool], take: Callable[[str], None],
                 release: Callable[[str], None]) -> None:
        self.instance = instance
        self.live: frozenset[str] = frozenset({instance})
        self._held, self._take, self._release = held, take, release
        self._previous: dict[str, VehicleState] = {}

    def mine(self, vid: str) -> bool:
        return owner_of(vid, self.live) == self.instance

    def claim(self, vid: str) -> None:
        """A vehicle became known (its plan arrived): take it if it hashes to this executor."""
        if self.mine(vid) and not self._held(vid):
            self._take(vid)

    def reassign(self, live: Iterable[str], vids: Iterable[str]) -> None:
        """The live executors are `live`: take the known vehicles `vids` that hash here, release the others."""
        self.live = frozenset(live) | {self.instance}
        for vid in list(vids):
            held = self._held(vid)
            if self.mine(vid) and not held:
                self._take(vid)
            elif not self.mine(vid) and held:
                log.info("%s: vehicle %s passes to %s", self.instance, vid, owner_of(vid, self.live))
                self._release(vid)

    def on_state(self, state: VehicleState) -> None:
        """Remember what other owners say of their vehicles (a take-over resumes from it)."""
        if state.owner != self.instance:
            self._previous[state.vid] = state

    def resume_from(self, vid: str, mission: str) -> VehicleState | None:
        """The last state another executor published of `vid` in `mission`, if any."""
        prev = self._previous.get(vid)
        return prev if prev is not None and prev.mission == mission else None
