"""From a plan to each vehicle's copy: the plan file to `VehiclePlan`s (paper 000), a team plan to
the drone's and the UGV's `VehicleTeamPlan` (paper 002): what an executor follows."""

from __future__ import annotations

from collections.abc import Collection

from common.bus.messages import PlanStep, TeamTask, VehiclePlan, VehicleTeamPlan
from common.domain.planfile import Plan
from common.domain.team_plan import TeamPlan


def vehicle_plans(plan: Plan, mission: str, t0: float = 0.0, back: Collection[str] = ()) -> dict[str, VehiclePlan]:
    """One VehiclePlan per vehicle: path entries with node position, node kind and arriving edge kind;
    `back`: the held vehicles this plan brings back (`VehiclePlan.rejoin`)."""
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
        out[vid] = VehiclePlan(vid=vid, mission=mission, map=plan.map, steps=steps, model=plan.model, t0=t0,
                               rejoin=vid in back)
    return out


def robot_plans(plan: TeamPlan, team: TeamTask, mission: str, t0: float = 0.0) -> dict[str, VehicleTeamPlan]:
    """The drone's and the UGV's copy of a team plan, each naming its partner."""
    return {
        team.drone: VehicleTeamPlan(vid=team.drone, mission=mission, robot="drone", partner=team.ugv, plan=plan, t0=t0),
        team.ugv: VehicleTeamPlan(vid=team.ugv, mission=mission, robot="ugv", partner=team.drone, plan=plan, t0=t0),
    }
