"""The turn in place a driving vehicle makes where its road bends, budgeted as a wait at the node.

Paper 000 times a path by its edges alone (§V), as if a vehicle changed direction on the spot. A
differential drive (§VI-B: "simple differential steering control") cannot: at a sharp corner it
stops and turns in place, and in the 32-vehicle soak it fell behind its plan by the turn's time at
the drive speed, 6-9 cm on a loaded machine's slow, late wheel commands, twice the 3 cm margin plans
keep for tracking error, and the tracking guard held it (docs/reliability.md). So a vehicle's speed
model may give a planning turn rate (`Speeds.turn`, rad/s; 0 budgets nothing, as in the paper), and
SIPP then leaves a drive edge only once the turn onto it is done:

- the turn is between the direction the vehicle arrived in and the edge's; it may drive off tail
  first (`services/executor/pure_pursuit.py`), so no turn is over 90 degrees;
- turns of up to `FREE_ANGLE` need no stop (pure pursuit steers through them);
- after a landing none: the flight turns the vehicle to face the road it lands on
  (`services/executor/trajectory.py`);
- from its start none: the executor turns it during the mission's lead (`MissionTiming.start_lead_s`),
  and a replan's start waits `replanning.TURN_ALLOWANCE_S`.

The executor turns during the wait (`VehicleController`). The ILP does not budget turns.
"""

from __future__ import annotations

import math

import numpy as np

from services.planner.graph.fleet_graph import FleetGraph

FREE_ANGLE = math.radians(30.0)
"""Turns up to this need no stop: pure pursuit steers through them at a small lag."""


def edge_headings(graph: FleetGraph) -> list[float]:
    """Per edge: its horizontal direction (rad) for a drive edge, NaN for the others (no turn is
    budgeted onto or off them)."""
    vec = graph.pos[graph.edges[:, 1]] - graph.pos[graph.edges[:, 0]]
    heading = np.arctan2(vec[:, 1], vec[:, 0])
    return [float(h) if k == "drive" else math.nan for h, k in zip(heading.tolist(), graph.edge_kinds, strict=True)]


def turn_time(heading_in: float, heading_out: float, rate: float) -> float:
    """Seconds a vehicle that arrived along `heading_in` (an edge's `edge_headings`) needs before it
    drives off along `heading_out` at `rate` rad/s (0: none budgeted; NaN either way: no drive)."""
    if rate <= 0.0 or math.isnan(heading_out) or math.isnan(heading_in):
        return 0.0
    d = abs(math.remainder(heading_out - heading_in, 2.0 * math.pi))
    angle = min(d, math.pi - d)
    return angle / rate if angle > FREE_ANGLE else 0.0
