"""From the plan file to each vehicle's `VehiclePlan` message (what an executor follows)."""

from __future__ import annotations

import zenoh

from common.bus.messages import PlanStep, VehiclePlan
from common.bus.pubsub import Publisher
from common.bus.service import Service
from common.domain.planfile import Plan


def vehicle_plans(plan: Plan, mission: str, t0: float = 0.0) -> dict[str, VehiclePlan]:
    """One VehiclePlan per vehicle: path entries with node position, node kind and arriving edge kind."""
    kinds = {(u, v): k for u, v, k in plan.graph.edges}
    out: dict[str, VehiclePlan] = {}
    for vid, path in plan.paths.items():
        steps = []
        prev = None
        for entry in path:
            node = plan.graph.nodes[entry.node]
            edge = kinds[(prev, entry.node)] if prev is not None and prev != entry.node else ""
            steps.append(PlanStep(node=entry.node, t=entry.t, pos=node.pos, kind=node.kind, edge=edge))
            prev = entry.node
        out[vid] = VehiclePlan(vid=vid, mission=mission, map=plan.map, steps=steps, model=plan.model, t0=t0)
    return out


class PlanPublisher:
    """Publishes VehiclePlans on `vehicle/<vid>/plan` for a service, one reused publisher per vehicle."""

    def __init__(self, service: Service) -> None:
        self._service = service
        self._pubs: dict[str, Publisher[VehiclePlan]] = {}

    def put(self, plans: dict[str, VehiclePlan]) -> None:
        for vid, vplan in plans.items():
            pub = self._pubs.get(vid)
            if pub is None:
                pub = self._pubs[vid] = self._service.publisher(
                    self._service.keys.vehicle(vid, "plan"), VehiclePlan, congestion_control=zenoh.CongestionControl.BLOCK
                )
            pub.put(vplan)
