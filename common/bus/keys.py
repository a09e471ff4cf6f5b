"""Every zenoh key expression of the fleet is built and parsed here (DESIGN.md, "Key expressions").

Layout: ``fleet/<fleet>/...``

- ``vehicle/<vid>/{pose,state,cmd,telemetry,plan,event}``; ground-air teams (paper 002):
  ``vehicle/<vid>/{team_plan,action,action_status}``
- ``mocap/frame`` (every vehicle's pose of one motion-capture frame, `PoseFrame`)
- ``gateway/<instance>/cmd`` (an executor's command batch for one gateway's vehicles, `CmdBatch`)
- ``planner/plan`` (queryable); ``planner/graph`` (queryable: a map's graph, for tools and the recorder)
- ``estop`` (the operator's emergency stop)
- ``mission/<id>/{start,abort,status,delay}``; ``mission/<id>/add`` (queryable: a running mission's new goals)
- ``sim/truth/<vid>``; ``sim/mocap`` (the simulated motion-capture system's frames); ``sim/fault/<vid>``
  (fault injection, simulators only: docs/reliability.md)
- ``alive/<service>/<instance>`` (liveliness tokens)
- ``stats/<service>/<instance>`` (each service's counters and figures, every few seconds)
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal, get_args

VehicleTopic = Literal["pose", "state", "cmd", "telemetry", "plan", "event", "team_plan", "action", "action_status"]
VEHICLE_TOPICS: tuple[VehicleTopic, ...] = get_args(VehicleTopic)
MissionTopic = Literal["start", "abort", "status", "add", "delay"]

DEFAULT_FLEET = "default"
_CHUNK = re.compile(r"^[A-Za-z0-9_.\-]+$")


def check_chunk(value: str, what: str) -> str:
    """A vehicle id, fleet name or instance must be one plain key chunk (no '/', '*', '$', '?', '#')."""
    if not _CHUNK.match(value):
        raise ValueError(f"{what} {value!r} is not a plain key chunk (letters, digits, '_', '-', '.')")
    return value


@dataclass(frozen=True)
class Keys:
    """Key expressions of one fleet."""

    fleet: str = DEFAULT_FLEET

    def __post_init__(self) -> None:
        check_chunk(self.fleet, "fleet name")

    @property
    def root(self) -> str:
        return f"fleet/{self.fleet}"

    def vehicle(self, vid: str, topic: VehicleTopic) -> str:
        check_chunk(vid, "vehicle id")
        return f"{self.root}/vehicle/{vid}/{topic}"

    def all_vehicles(self, topic: VehicleTopic) -> str:
        return f"{self.root}/vehicle/*/{topic}"

    def parse_vehicle(self, key: str) -> tuple[str, str] | None:
        """``fleet/<f>/vehicle/<vid>/<topic>`` -> (vid, topic); None for any other key."""
        prefix = f"{self.root}/vehicle/"
        if not key.startswith(prefix):
            return None
        parts = key[len(prefix):].split("/")
        if len(parts) != 2 or parts[1] not in VEHICLE_TOPICS:
            return None
        return parts[0], parts[1]

    @property
    def mocap_frame(self) -> str:
        """Every vehicle's pose of one motion-capture frame (`PoseFrame`)."""
        return f"{self.root}/mocap/frame"

    def gateway_cmd(self, instance: str) -> str:
        """Command batches (`CmdBatch`) for the vehicles of gateway `instance`."""
        check_chunk(instance, "gateway instance")
        return f"{self.root}/gateway/{instance}/cmd"

    def executor_states(self, instance: str) -> str:
        """The states executor `instance` published in one control cycle (`VehicleStates`)."""
        check_chunk(instance, "executor instance")
        return f"{self.root}/executor/{instance}/states"

    @property
    def all_executor_states(self) -> str:
        return f"{self.root}/executor/*/states"

    @property
    def planner_plan(self) -> str:
        return f"{self.root}/planner/plan"

    @property
    def estop(self) -> str:
        """The operator's emergency stop (`EmergencyStop`)."""
        return f"{self.root}/estop"

    @property
    def planner_graph(self) -> str:
        return f"{self.root}/planner/graph"

    def mission(self, mission_id: str, topic: MissionTopic) -> str:
        check_chunk(mission_id, "mission id")
        return f"{self.root}/mission/{mission_id}/{topic}"

    def all_missions(self, topic: MissionTopic) -> str:
        return f"{self.root}/mission/*/{topic}"

    def sim_truth(self, vid: str) -> str:
        check_chunk(vid, "vehicle id")
        return f"{self.root}/sim/truth/{vid}"

    @property
    def all_sim_truth(self) -> str:
        return f"{self.root}/sim/truth/*"

    @property
    def sim_truths(self) -> str:
        """Every simulated vehicle's truth of one instant (`SimTruthFrame`)."""
        return f"{self.root}/sim/truths"

    @property
    def sim_mocap(self) -> str:
        """Frames of the simulated motion-capture system."""
        return f"{self.root}/sim/mocap"

    def sim_fault(self, vid: str) -> str:
        check_chunk(vid, "vehicle id")
        return f"{self.root}/sim/fault/{vid}"

    @property
    def all_sim_faults(self) -> str:
        return f"{self.root}/sim/fault/*"

    def alive(self, service: str, instance: str) -> str:
        check_chunk(service, "service name")
        check_chunk(instance, "instance name")
        return f"{self.root}/alive/{service}/{instance}"

    def all_alive(self, service: str = "*") -> str:
        return f"{self.root}/alive/{service}/*"

    def parse_alive(self, key: str) -> tuple[str, str] | None:
        prefix = f"{self.root}/alive/"
        if not key.startswith(prefix):
            return None
        parts = key[len(prefix):].split("/")
        return (parts[0], parts[1]) if len(parts) == 2 else None

    def stats(self, service: str, instance: str) -> str:
        check_chunk(service, "service name")
        check_chunk(instance, "instance name")
        return f"{self.root}/stats/{service}/{instance}"

    def all_stats(self, service: str = "*") -> str:
        return f"{self.root}/stats/{service}/*"
