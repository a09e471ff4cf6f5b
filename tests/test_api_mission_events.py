"""What the API's mission handle makes of its mission's aborts (`services/api/_mission.py`): the
mission's own abort is its "aborted" event; a vehicle the mission stops or holds alone while the
others go on (`MissionAbort.vehicles`: a replan could not place it) is that vehicle's event, not
the mission's abort. A real zenoh session; the handle's mission process is not launched."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.messages import MissionAbort
from common.bus.pubsub import Publisher
from services.api._mission import Mission
from services.api._types import MissionEvent

KEYS = Keys("apievents")


@pytest.mark.timeout(30)
def test_a_vehicle_stopped_or_held_alone_is_its_event_and_only_the_missions_abort_is_aborted(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    held = "cf2: held where it is, no plan around the vehicles that left (replanning failed)"
    stopped = "cf3: stopped where it is, no plan around the vehicles that left (replanning failed)"

    async def scenario() -> list[MissionEvent]:
        session = zsession()
        seen: list[MissionEvent] = []
        mission = Mission(session, KEYS, "m1", ["cf1", "cf2", "cf3"], [], {}, on_event=seen.append)
        abort = Publisher(session, KEYS.mission("m1", "abort"), MissionAbort)
        try:
            await asyncio.sleep(0.5)
            abort.put(MissionAbort(mission="m1", reason=held, vehicles=["cf2"], hold=True))
            abort.put(MissionAbort(mission="m1", reason=stopped, vehicles=["cf3"]))
            await asyncio.sleep(0.5)
            assert not any(e.kind == "aborted" for e in seen), seen
            abort.put(MissionAbort(mission="m1", reason="the operator's"))
            await asyncio.sleep(0.5)
        finally:
            for sub in mission._subs:
                sub.close()
        return seen

    seen = asyncio.run(scenario())
    assert [(e.kind, e.vid, e.detail) for e in seen] == [("vehicle_event", "cf2", held), ("vehicle_event", "cf3", stopped),
                                                         ("aborted", "", "the operator's")], seen
