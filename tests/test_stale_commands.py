"""A gateway's stale-command landing is a mission's fault only when the commands stay away
(services/mission/stale_commands.py): a starved executor that runs again, or a vehicle another
executor took over, flies on."""

from __future__ import annotations

import time

from common.bus.messages import VehicleEvent
from common.bus.session import ZenohConfig
from common.domain.planfile import Task
from services.mission.runner import MissionRunner, MissionSpec
from services.mission.stale_commands import RESUME_GRACE_S

TASKS = {"cf1": Task(start="WP10", goal="EP8"), "cf2": Task(start="EP7", goal="WP9")}


def runner() -> MissionRunner:
    """A mission not started (no session needed to take events)."""
    return MissionRunner(MissionSpec(map="town", tasks=TASKS), ZenohConfig.client("tcp/127.0.0.1:1"), progress=False)


def event(kind: str, vid: str = "cf1") -> VehicleEvent:
    return VehicleEvent(vid=vid, t=0.0, kind=kind, detail="no command for 0.21 s in flight: hover, then land")


def test_commands_back_within_the_grace_are_no_fault() -> None:
    r = runner()
    r._on_event(event("stale_cmd_landing"), "")
    assert r.fault is None
    r._on_event(event("cmd_resumed"), "")
    r._check_stale(time.time() + 10 * RESUME_GRACE_S)
    assert r.fault is None
    assert any("came back" in e for e in r.events), r.events


def test_commands_away_past_the_grace_are_the_missions_fault() -> None:
    r = runner()
    r._on_event(event("stale_cmd_landing"), "")
    r._check_stale(time.time() + 0.5 * RESUME_GRACE_S)
    assert r.fault is None
    r._check_stale(time.time() + RESUME_GRACE_S + 0.1)
    assert r.fault is not None and "cf1" in r.fault and "stale_cmd_landing" in r.fault, r.fault
    r._on_event(event("cmd_resumed"), "")  # too late: the mission has ended already
    assert "stale_cmd_landing" in r.fault


def test_a_vehicle_its_gateway_landed_is_a_fault_at_once() -> None:
    r = runner()
    r._on_event(event("stale_cmd_landing"), "")
    r._on_event(event("landed"), "")
    assert r.fault is not None and "landed by its gateway" in r.fault, r.fault


def test_a_resumed_vehicle_taken_over_again_is_judged_afresh() -> None:
    r = runner()
    r._on_event(event("stale_cmd_landing"), "")
    r._on_event(event("cmd_resumed"), "")
    r._on_event(event("landed", "cf2"), "")  # another vehicle's ordinary landing: nothing
    r._on_event(event("stale_cmd_landing"), "")
    r._check_stale(time.time() + RESUME_GRACE_S + 0.1)
    assert r.fault is not None and r.fault.startswith("cf1"), r.fault
