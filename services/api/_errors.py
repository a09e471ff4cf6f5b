"""The API's exceptions: every one says what failed and why; those about one vehicle name it."""

from __future__ import annotations

import re

_TASK_FIELD = re.compile(r"tasks\.([A-Za-z0-9_.\-]+?)(?:\.(?:start|goal))?:")


class FleetError(Exception):
    """Base of every error the API raises."""


class ConnectError(FleetError):
    """No fleet could be reached or started (no router, bad credentials, services not up)."""


class PlanningError(FleetError):
    """The planner refused or failed; `vehicle` is the vehicle its message names, if any."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason
        match = _TASK_FIELD.search(reason)
        self.vehicle: str | None = match.group(1) if match else None


class MissionFailed(FleetError):
    """A mission ended without every vehicle arriving; `result` says how far each got."""

    def __init__(self, mission: str, reason: str, result: object | None = None) -> None:
        super().__init__(f"mission {mission}: {reason}")
        self.mission = mission
        self.reason = reason
        self.result = result


class VehicleError(FleetError):
    """Something about one vehicle: `vehicle` and `reason`."""

    def __init__(self, vehicle: str, reason: str) -> None:
        super().__init__(f"{vehicle}: {reason}")
        self.vehicle = vehicle
        self.reason = reason


class UnknownVehicle(VehicleError):
    """The fleet does not see this vehicle (no executor state, no motion-capture pose)."""


class VehicleBusy(VehicleError):
    """A running mission owns the vehicle (its runner is alive and the vehicle is in its plan)."""

    def __init__(self, vehicle: str, mission: str, reason: str) -> None:
        super().__init__(vehicle, reason)
        self.mission = mission


class CommandRefused(VehicleError):
    """A single-vehicle command that cannot be flown as asked (not on a spot, goal taken, ...)."""
