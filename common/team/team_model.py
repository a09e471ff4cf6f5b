"""Robot, sensor and cost parameters of the ground-air team (002 §III-B, §V-A)."""

from __future__ import annotations

import msgspec


class TeamModel(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Everything the controllers, the lattice and the simulator assume about the two robots.

    Costs are proportional to distance travelled by each vehicle (002 §IV-D), in metre-equivalents;
    metric drone motions carry a high cost to keep them rare (002 §III-B).
    """

    clearance: float = 0.3
    """A drone cell at altitude z is blocked where an obstacle top is above z - clearance."""
    ir_range: float = 1.5
    """Side IR range sensors (002 §V-A: 6 Sharp IR sensors, 1.5 m)."""
    landmark_range: float = 4.0
    """Camera range for static landmarks (GOTOLANDMARK_STAT precondition and LANDMARK_SIGHTED)."""
    ugv_range: float = 2.5
    """Camera range for the UGV's fiducials (GOTOLANDMARK_DYN precondition)."""
    station_cells: int = 2
    """GOTOLANDMARK targets: cells within this Chebyshev distance of the landmark (or UGV)."""
    metric_cells: tuple[int, ...] = (1, 2)
    """METRICSTEP lengths in cells (short motions only, 002 §III-B)."""
    ugv_height: float = 0.8
    """Height of the UGV's marker hexagon; the drone flies above it (no drone-UGV collisions)."""
    cost_action: float = 0.1
    """Added to every drone controller action: switching controllers takes time."""
    cost_follow: float = 1.0
    cost_landmark: float = 1.0
    cost_metric: float = 5.0
    cost_metric_turn: float = 0.5
    cost_altitude: float = 1.0
    cost_ugv: float = 1.0
    cost_ugv_turn: float = 0.25
    """Per 45 degree turn in place of the UGV (time-proportional)."""
    drone_speed: float = 0.5
    ugv_speed: float = 0.5
    ugv_turn_rate: float = 45.0
    """Degrees per second, for simulated timing only."""
