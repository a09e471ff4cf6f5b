"""When a gateway's stale-command landing is a mission's fault.

A gateway that hears no command for a flying vehicle for `stale_s` (0.2 s) hovers it, then lands
it (`stale_cmd_landing`, docs/radio.md), and gives it back once fresh commands have come for
0.1 s (`cmd_resumed`, `GatewayParams.resume_s`). That silence is the bus or the executor failing,
or only an executor that did not run for a few tenths of a second (a starved process), or one that
died and whose vehicles pass to another executor (1.0-1.2 s after a host lost its link:
docs/security.md). The last two come back on their own; the plan goes on, and a vehicle that
drifted from it meanwhile is held by its executor's tracking guard (`tracking_hold`, a fault of
its own). So a mission takes a stale-command landing for a fault only when the commands do not
come back within `RESUME_GRACE_S`, or the gateway landed the vehicle first (`landed`).
"""

from __future__ import annotations

from common.bus.messages import VehicleEvent

RESUME_GRACE_S = 2.0
"""s: how long a vehicle's commands may be away after its gateway took it over before the mission
takes it for a fault: a take-over (1.0-1.2 s measured, over 1.5 s seen once in CI) fits; the
gateway's landing (0.5 s of hover, then 0.2 m/s down from the cruise height) has not ended."""


class StaleCommands:
    """The vehicles whose gateway took them over for stale commands, until theirs come back."""

    def __init__(self, grace_s: float = RESUME_GRACE_S) -> None:
        self.grace_s = grace_s
        self._since: dict[str, tuple[float, VehicleEvent]] = {}

    def took_over(self, event: VehicleEvent, now: float) -> None:
        """A `stale_cmd_landing` event that arrived at `now` (the first one counts)."""
        self._since.setdefault(event.vid, (now, event))

    def resumed(self, vid: str, now: float) -> float | None:
        """A `cmd_resumed` of `vid`: how long it was taken over, or None if it was not (now)."""
        since = self._since.pop(vid, None)
        return None if since is None else now - since[0]

    def landed(self, vid: str) -> VehicleEvent | None:
        """The gateway landed `vid`: its take-over, now a fault, or None if it was not taken over."""
        since = self._since.pop(vid, None)
        return None if since is None else since[1]

    def overdue(self, now: float) -> list[VehicleEvent]:
        """The take-overs whose commands did not come back within the grace: now faults."""
        late = [vid for vid, (since, _event) in self._since.items() if now - since > self.grace_s]
        return [self._since.pop(vid)[1] for vid in late]
