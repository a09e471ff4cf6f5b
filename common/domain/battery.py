"""What a vehicle's battery still holds, from what it reports (paper 000 §V-C, eq. 4-6).

The planner's budget of eq. 6 is the usable charge (capacity - reserve) of a full battery, and
eq. 4-5 draw the current at the model's voltage. A real vehicle starts a mission with some charge
used and at its own voltage: its budget is what is left, and since the current it draws for a power
is P / V at its own voltage (eq. 4), a vehicle below the model's voltage draws more charge for the
same plan. `usable_ah` folds both into a budget in the planner's units (charge at the model's
voltage): (usable - used) x V_vehicle / V_model, with V_vehicle never above the model's (the
voltage sags as the battery drains, so the start voltage would be optimistic).

The charge used is read from the resting voltage through a 1S Li-Po open-circuit curve (generic,
assumed: not measured on the Crazyflie's 250 mAh cell; the Crazyflie firmware reports `pm.vbat`, not
charge). The simulator's battery uses the same curve.
"""

from __future__ import annotations

from bisect import bisect_right

from common.domain.vehicle_model import VehicleModel

OCV_SOC = (0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
OCV_V = (3.27, 3.45, 3.68, 3.74, 3.77, 3.79, 3.82, 3.87, 3.92, 3.98, 4.06, 4.20)


def open_circuit_voltage(soc: float) -> float:
    """Li-Po open-circuit voltage (V) at state of charge `soc` in [0, 1] (linear interpolation)."""
    return _interpolate(OCV_SOC, OCV_V, soc)


def state_of_charge(vbat: float) -> float:
    """The state of charge in [0, 1] whose open-circuit voltage is `vbat` (the curve inverted)."""
    return _interpolate(OCV_V, OCV_SOC, vbat)


def charge_used_ah(vbat: float, model: VehicleModel) -> float:
    """Charge used (Ah) of a battery resting at `vbat` (idle: the internal resistance's drop is small)."""
    return (1.0 - state_of_charge(vbat)) * model.capacity_ah


def usable_ah(model: VehicleModel, charge_used: float = 0.0, voltage: float = 0.0) -> float:
    """Eq. 6's budget in the planner's units for a vehicle that used `charge_used` Ah and is at
    `voltage` V (0: the model's): see the module doc. May be negative (already below the reserve)."""
    v = model.voltage if voltage <= 0.0 else min(voltage, model.voltage)
    return (model.usable_ah - charge_used) * v / model.voltage


def _interpolate(xs: tuple[float, ...], ys: tuple[float, ...], x: float) -> float:
    x = min(max(x, xs[0]), xs[-1])
    i = min(max(bisect_right(xs, x), 1), len(xs) - 1)
    x0, x1, y0, y1 = xs[i - 1], xs[i], ys[i - 1], ys[i]
    return y0 + (y1 - y0) * (x - x0) / (x1 - x0)
