"""Per-vehicle mode state machine (paper 000 §VI-C: "a state machine that determines based off of
the node type whether to send commands to the driving or flying controller, and if it chooses the
flying controller, whether to takeoff, land, or fly").

The allowed transitions are data (`TRANSITIONS`); a request outside the table is logged, counted
and refused, never raised.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import StrEnum

from common.domain.vehicle_model import EdgeKind, NodeKind

log = logging.getLogger(__name__)


class Mode(StrEnum):
    PARKED = "parked"
    """On the ground, wheels and motors off: before the mission, or waiting at a parking node."""
    DRIVING = "driving"
    """Following a drive edge (or waiting on a road node) with the wheel controller."""
    TAKING_OFF = "taking_off"
    """Following a takeoff edge with the flight controller."""
    FLYING = "flying"
    """Following a fly edge, or hovering through a wait at an air node."""
    LANDING = "landing"
    """Following a land edge, or a fault's descent to the nearest safe point, until touchdown."""
    HOLDING = "holding"
    """On the ground, stopped by a fault (stale pose, lost link) that may clear, or by the tracking
    guard (for good, unless held rejoinable and brought back into the plan), or where
    an emergency descent in a take-off or landing of its plan came down (it may be brought back)."""
    HOVERING = "hovering"
    """Airborne, held where it was by the tracking guard (off its plan) until the mission aborts,
    or, held rejoinable (late on its way, or for another's sake), until the mission's plan brings
    it back (then flying on, or in its take-off)."""
    EMERGENCY_LANDING = "emergency_landing"
    """Airborne without a trustworthy pose: a blind, level descent, then motors off (done, or
    holding if it came down, seen, in the column of the take-off or landing it was in)."""
    DONE = "done"
    """On the ground, motors and wheels off for good: at the goal, or after an abort or low battery."""


AIRBORNE: frozenset[Mode] = frozenset({Mode.TAKING_OFF, Mode.FLYING, Mode.LANDING, Mode.HOVERING,
                                       Mode.EMERGENCY_LANDING})
GROUNDED: frozenset[Mode] = frozenset(Mode) - AIRBORNE

TRANSITIONS: dict[Mode, frozenset[Mode]] = {
    Mode.PARKED: frozenset({Mode.DRIVING, Mode.TAKING_OFF, Mode.HOLDING, Mode.DONE}),
    Mode.DRIVING: frozenset({Mode.PARKED, Mode.TAKING_OFF, Mode.HOLDING, Mode.DONE}),
    Mode.TAKING_OFF: frozenset({Mode.FLYING, Mode.LANDING, Mode.HOVERING, Mode.EMERGENCY_LANDING}),
    Mode.FLYING: frozenset({Mode.LANDING, Mode.HOVERING, Mode.EMERGENCY_LANDING}),
    Mode.LANDING: frozenset({Mode.PARKED, Mode.DRIVING, Mode.TAKING_OFF, Mode.HOLDING, Mode.HOVERING, Mode.DONE,
                             Mode.EMERGENCY_LANDING}),
    Mode.HOVERING: frozenset({Mode.FLYING, Mode.TAKING_OFF, Mode.LANDING, Mode.EMERGENCY_LANDING}),
    Mode.HOLDING: frozenset({Mode.PARKED, Mode.DRIVING, Mode.TAKING_OFF, Mode.DONE}),
    Mode.EMERGENCY_LANDING: frozenset({Mode.DONE, Mode.HOLDING}),
    Mode.DONE: frozenset({Mode.PARKED}),
}
"""Allowed transitions. Ground <-> air only through TAKING_OFF and (EMERGENCY_)LANDING; DONE is
left only by loading a new plan."""

_EDGE_MODE: dict[str, Mode] = {"drive": Mode.DRIVING, "takeoff": Mode.TAKING_OFF,
                               "fly": Mode.FLYING, "land": Mode.LANDING}


def segment_mode(edge: EdgeKind | str, node_kind: NodeKind, prev: Mode) -> Mode:
    """The planned mode between two path entries: the arriving edge's kind for a traversal (`edge`
    non-empty); for a wait (`edge` == ""), hovering at an air node, parked at a parking node, and
    otherwise the ground mode the vehicle was in (§VI-B)."""
    if edge:
        return _EDGE_MODE[edge]
    if node_kind == "air":
        return Mode.FLYING
    if node_kind == "parking" or prev not in (Mode.DRIVING, Mode.LANDING):
        return Mode.PARKED
    return Mode.DRIVING


@dataclass(frozen=True, slots=True)
class Transition:
    t: float
    src: Mode
    dst: Mode
    reason: str


class ModeMachine:
    """The current mode of one vehicle and its history of accepted transitions."""

    def __init__(self, vid: str, initial: Mode = Mode.PARKED) -> None:
        self.vid = vid
        self.mode = initial
        self.history: list[Transition] = []
        self.refused = 0
        self._logged: set[Mode] = set()

    def request(self, dst: Mode, t: float, reason: str) -> bool:
        """Go to `dst` if the table allows it (staying is always allowed); refuse, count and log
        (once per target while in this mode) otherwise."""
        if dst == self.mode:
            return True
        if dst not in TRANSITIONS[self.mode]:
            self.refused += 1
            if dst not in self._logged:  # once per target until the mode changes, not every tick
                self._logged.add(dst)
                log.warning("%s: refused mode transition %s -> %s (%s)", self.vid, self.mode, dst, reason)
            return False
        self._logged.clear()
        self.history.append(Transition(t, self.mode, dst, reason))
        log.info("%s: %s -> %s (%s)", self.vid, self.mode, dst, reason)
        self.mode = dst
        return True

    def resume(self, mode: Mode, t: float, reason: str) -> None:
        """Adopt the mode another executor left the vehicle in. A take-over changes who controls
        the vehicle, not how it moves, so the table does not apply; the history records it."""
        self._logged.clear()
        self.history.append(Transition(t, self.mode, mode, reason))
        log.warning("%s: %s -> %s (%s)", self.vid, self.mode, mode, reason)
        self.mode = mode

    @property
    def airborne(self) -> bool:
        return self.mode in AIRBORNE

    def sequence(self) -> list[Mode]:
        """Modes visited so far, in order, starting with the initial one."""
        if not self.history:
            return [self.mode]
        return [self.history[0].src, *(tr.dst for tr in self.history)]
