"""What the API hands back: frozen msgspec Structs (they cross threads and may be logged or sent)."""

from __future__ import annotations

from typing import Literal

import msgspec

EventKind = Literal["planned", "started", "progress", "mode", "arrived", "vehicle_event", "aborted", "ended"]


class VehicleInfo(msgspec.Struct, frozen=True):
    """A vehicle as the fleet sees it now: its executor's latest state (before any plan: its
    motion-capture pose, mode "idle") and its gateway's telemetry.
    `mission` is the mission whose plan it holds ("" for none); `busy` says whether that mission is
    still running (its runner is alive), in which case single-vehicle commands are refused."""

    vid: str
    mode: str
    x: float
    y: float
    z: float
    yaw: float
    mission: str
    busy: bool
    arrived: bool
    owner: str
    battery_v: float | None
    link_quality: float | None
    capabilities: str
    t: float


class MissionEvent(msgspec.Struct, frozen=True):
    """One thing that happened in a mission. `kind`: "planned" (a vehicle's plan was handed out:
    again for each new goal or replan), "started" (the common start time is set), "progress" (a
    vehicle reached path entry `step` of `steps`), "mode" (a vehicle's mode changed), "arrived" (at
    its goal: again at each new goal), "vehicle_event" (a fault or other event
    of the vehicle: `detail`; one its mission stopped or held alone too), "aborted" (the mission's
    abort was published: `detail` is why), "ended" (the
    mission is over: `detail` is its reason)."""

    kind: EventKind
    mission: str
    t: float
    vid: str = ""
    mode: str = ""
    step: int = 0
    steps: int = 0
    detail: str = ""


class VehicleOutcome(msgspec.Struct, frozen=True):
    """How one vehicle did in a mission, from its executor's states: its latest arrival at a goal,
    after the start (None if it never arrived), energy used (J), largest tracking error (m), last
    mode and position."""

    vid: str
    arrived: bool
    arrival_s: float | None
    energy_j: float
    max_tracking_error: float
    mode: str
    position: tuple[float, float, float]


class MissionResult(msgspec.Struct, frozen=True):
    """A finished mission: `ok` when every vehicle arrived with no contact; `reason` as the mission
    runner gives it; `summary` its printed summary (ground-truth separation included)."""

    mission: str
    ok: bool
    reason: str
    duration_s: float
    vehicles: dict[str, VehicleOutcome]
    events: list[str]
    summary: str
