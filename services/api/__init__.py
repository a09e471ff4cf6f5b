"""The fleet as a Python library: the one module users import (`docs/api.md`).

    from services.api import Fleet

    with Fleet.open() as fleet:                 # connect (FLEET_ZENOH_CONNECT) or start a simulated fleet
        print(fleet.vehicles())                 # every vehicle with its live state
        plan = fleet.plan("town", {"cf1": ("WP1", "EP4")})
        result = fleet.run_mission("town", {"cf1": ("WP1", "EP4")}, on_event=print)
        fleet.go_to("cf1", "EP5")               # one vehicle, through the executors

`Fleet` blocks; `AsyncFleet` is the same for asyncio. `__all__` is the whole public surface: every
other name in `services.api` is private and may change (tests/test_api_surface.py keeps it so).
The API talks to the fleet over the bus only, as any client does, and runs missions with the
fleet's own mission runner (`fleet mission run`, `fleet mission team`) as a process; it never
imports another service (docs/architecture.md).
"""

import logging as _logging

from common.bus.messages import TeamTask, Telemetry, VehiclePlan
from common.domain.planfile import Plan, Task
from common.domain.team_plan import TeamPlan
from services.api._errors import (
    CommandRefused,
    ConnectError,
    FleetError,
    MissionFailed,
    PlanningError,
    UnknownVehicle,
    VehicleBusy,
    VehicleError,
)
from services.api._fleet import AsyncFleet
from services.api._mission import Mission
from services.api._sync import Fleet, SyncMission
from services.api._types import MissionEvent, MissionResult, VehicleInfo, VehicleOutcome

__all__ = [
    "AsyncFleet", "Fleet", "Mission", "SyncMission",
    "VehicleInfo", "MissionEvent", "MissionResult", "VehicleOutcome",
    "Plan", "Task", "TeamTask", "TeamPlan", "VehiclePlan", "Telemetry",
    "FleetError", "ConnectError", "PlanningError", "MissionFailed",
    "VehicleError", "UnknownVehicle", "VehicleBusy", "CommandRefused",
]

_logging.getLogger("common").addHandler(_logging.NullHandler())  # a library: the application decides what is shown
