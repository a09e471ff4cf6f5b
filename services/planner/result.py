"""What every planner returns, and how a result becomes the plan file (DESIGN.md)."""

from __future__ import annotations

from dataclasses import dataclass, field

from common.domain.planfile import PathEntry, Plan, Task
from services.planner.graph.fleet_graph import FleetGraph


@dataclass
class PlanResult:
    """ok: every vehicle has a path. On failure `error` says why and `failed_vehicle` names the
    vehicle that could not be placed (prioritized planning) when there is one. `priority`: the
    order the vehicles were planned in, highest first (prioritized planning only)."""

    ok: bool
    paths: dict[str, list[PathEntry]] = field(default_factory=dict)
    cost: float = 0.0
    planning_time_s: float = 0.0
    error: str = ""
    failed_vehicle: str = ""
    mip_gap: float | None = None
    stats: dict[str, float] = field(default_factory=dict)
    priority: list[str] = field(default_factory=list)
    stranded: dict[str, str] = field(default_factory=dict)
    """Replanning: vehicles given a goal short of their own, and why theirs was out of reach."""
    timed_out: bool = False
    """Without a plan: the time limit ended the search with more left to try."""
    unplaceable: list[str] = field(default_factory=list)
    """Replanning, without a plan: every vehicle no priority order can place (`failed_vehicle` the
    first)."""


def to_plan(graph: FleetGraph, map_name: str, planner: str, mu: float, tasks: dict[str, Task], result: PlanResult) -> Plan:
    return Plan(
        map=map_name,
        planner=planner,
        mu=mu,
        model=graph.plan_model(),
        graph=graph.to_plan_graph(),
        tasks=tasks,
        paths=result.paths,
        cost=result.cost,
        planning_time_s=result.planning_time_s,
        dt=graph.dt,
        mip_gap=result.mip_gap,
    )


def battery_shortfall(task: Task, needed: float, usable: float) -> str:
    """Why a task does not fit its vehicle's battery (eq. 6), with the shortfall in Ah."""
    used = f", {task.charge_used_ah:.4f} Ah already used" if task.charge_used_ah else ""
    at = f" at {task.voltage:.2f} V" if task.voltage else ""
    return (f"battery: {task.start!r} -> {task.goal!r} needs at least {needed:.4f} Ah, more than the usable "
            f"{max(usable, 0.0):.4f} Ah (eq. 6: capacity - reserve{used}{at}): short by {needed - max(usable, 0.0):.4f} Ah")
