"""Vehicle model and the time-energy cost of paper 000 (§V-B eq. 1-3, §V-C eq. 4-5).

The model is the one piece every part of the fleet agrees on: the planner prices edges with it,
the validator recomputes costs with it, the simulator drains batteries with it.
Defaults follow paper 000 Table I-II (a Crazyflie 2.0 with a wheel base).
"""

from __future__ import annotations

from typing import Literal

import msgspec

G = 9.81  # m/s^2

EdgeKind = Literal["drive", "takeoff", "fly", "land"]
EDGE_KINDS: tuple[EdgeKind, ...] = ("drive", "takeoff", "fly", "land")
NodeKind = Literal["parking", "land", "waypoint", "air", "helipad"]
NODE_KINDS: tuple[NodeKind, ...] = ("parking", "land", "waypoint", "air", "helipad")
Capabilities = Literal["fly+drive", "fly", "drive"]
"""What a vehicle can do (DESIGN.md "Vehicles"): a flying car, a stock Crazyflie, a ground robot."""
CAPABLE_EDGES: dict[Capabilities, frozenset[EdgeKind]] = {
    "fly+drive": frozenset(EDGE_KINDS),
    "fly": frozenset(("takeoff", "fly", "land")),
    "drive": frozenset(("drive",)),
}
"""The edge kinds each kind of vehicle may traverse: the planners use no other."""


class Speeds(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Nominal speed per edge kind in m/s (Table II: driving 0.1, flying 0.3), and `turn`: the rate
    (rad/s) at which plans budget a driving vehicle's turn in place where its road bends, 0 for
    none (paper 000 times a path by its edges alone; a differential drive stops at a sharp corner to
    turn, and fell behind its plan by the turn's time: `services/planner/sipp/turns.py`)."""

    drive: float = 0.1
    takeoff: float = 0.2
    fly: float = 0.3
    land: float = 0.2
    turn: float = 0.0


class Powers(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Average power draw per mode in W (Table II: wheels 0.60, flying car 7.83).

    `idle` (powered, motors off) is not in the paper: 40 mA at 3.7 V for the Crazyflie's
    electronics, an estimate from the Crazyflie 2.x datasheet's standby draw.
    """

    drive: float = 0.60
    fly: float = 7.83
    idle: float = 0.15


class VehicleModel(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A flying car: a cylinder of `radius` x `height` with the energetics of Table II.

    capacity_ah: the usable charge. 0.176 Ah reproduces Table II's 5.0 min of flight at
    7.83 W on a 3.7 V cell (7.83 W * 300 s / 3.7 V / 3600 s/h).
    margin: clearance (m) that plans keep between bodies on top of contact, for tracking error:
    planners and the validator work on the envelope (`envelope()`), the body grown by margin/2 on
    every side. A plan file's radius and height are that envelope; its margin says how much of it is
    clearance, so the physical body is radius - margin/2 by height - margin.
    """

    radius: float = 0.06
    height: float = 0.05
    mass: float = 0.041
    speed: Speeds = Speeds()
    power: Powers = Powers()
    voltage: float = 3.7
    capacity_ah: float = 0.176
    reserve_ah: float = 0.018
    margin: float = 0.0

    def __post_init__(self) -> None:
        for name in ("radius", "height", "mass", "voltage", "capacity_ah"):
            if getattr(self, name) <= 0:
                raise msgspec.ValidationError(f"`{name}` must be positive")
        for kind in EDGE_KINDS:
            if getattr(self.speed, kind) <= 0:
                raise msgspec.ValidationError(f"`speed.{kind}` must be positive")
        if self.speed.turn < 0:
            raise msgspec.ValidationError("`speed.turn` must not be negative")
        if not 0 <= self.reserve_ah < self.capacity_ah:
            raise msgspec.ValidationError("`reserve_ah` must be in [0, capacity_ah)")
        if self.margin < 0:
            raise msgspec.ValidationError("`margin` must not be negative")

    def envelope(self) -> VehicleModel:
        """The model planners work on: radius and height grown by the margin (see the class doc)."""
        return msgspec.structs.replace(self, radius=self.radius + self.margin / 2, height=self.height + self.margin)

    def body(self) -> tuple[float, float]:
        """The physical (radius, height) of a model that is an envelope (a plan file's model)."""
        return self.radius - self.margin / 2, self.height - self.margin

    @property
    def usable_ah(self) -> float:
        """Charge a plan may use: capacity minus reserve (the C_low of §V-C)."""
        return self.capacity_ah - self.reserve_ah

    def edge_speed(self, kind: EdgeKind) -> float:
        return float(getattr(self.speed, kind))

    def mode_power(self, kind: EdgeKind) -> float:
        """Power drawn while traversing an edge of `kind`: driving or flying (§V-B)."""
        return self.power.drive if kind == "drive" else self.power.fly

    def wait_power(self, airborne: bool) -> float:
        """Power drawn while waiting: hovering costs fly power, the ground idle power."""
        return self.power.fly if airborne else self.power.idle

    def edge_duration(self, kind: EdgeKind, length: float) -> float:
        return length / self.edge_speed(kind)

    def edge_energy(self, kind: EdgeKind, length: float, dz: float, duration: float | None = None) -> float:
        """Work in J over an edge: eq. 1 when flying (with the potential-energy gain), eq. 2 when driving.

        `duration` overrides length/speed (edges of the uniform-time-step graph are stretched to dt).
        """
        t = self.edge_duration(kind, length) if duration is None else duration
        if kind == "drive":
            return self.power.drive * t
        return self.power.fly * t + self.mass * G * max(dz, 0.0)

    def charge_ah(self, power_w: float, duration_s: float) -> float:
        """Charge drawn (Ah): eq. 4 I = P/V, eq. 5 I_c = I d / v = I t."""
        return power_w / self.voltage * duration_s / 3600.0

    def edge_charge(self, kind: EdgeKind, duration: float) -> float:
        return self.charge_ah(self.mode_power(kind), duration)

    def wait_charge(self, duration: float, airborne: bool) -> float:
        return self.charge_ah(self.wait_power(airborne), duration)

    def run_time_s(self, power_w: float, usable: bool = False) -> float:
        """Seconds a full battery (or only its usable part, above the reserve) lasts at `power_w`
        (eq. 4-5): Table II's run time as the model sees it."""
        return (self.usable_ah if usable else self.capacity_ah) / self.charge_ah(power_w, 1.0)

    def cost_of_transport(self, power_w: float, speed: float) -> float:
        """Table II's COT: P / (m g v), dimensionless."""
        return power_w / (self.mass * G * speed)


class CostScale(msgspec.Struct, frozen=True):
    """The normalisers of eq. 3: the largest edge energy W_max (J) and duration t_max (s) in the graph."""

    w_max: float
    t_max: float

    def cost(self, mu: float, energy: float, duration: float) -> float:
        """Eq. 3: c = mu W / W_max + (1 - mu) t / t_max."""
        return mu * energy / self.w_max + (1.0 - mu) * duration / self.t_max
