"""Onboard control mode (DESIGN.md "Vehicles"; issue 17): the vehicle flies on its own estimator and
controller, and the executor sends it full-state setpoints (position, velocity and acceleration
feed-forward, yaw) along the same reference the LQR of paper 000 §VI-B would track in offboard
mode. The gateway streams the vehicle's motion-capture pose to its Kalman estimator (external pose)
and has set the Mellinger controller, which follows the feed-forward (crazyswarm2's setup;
docs/control.md "Onboard control mode").

A vehicle is in onboard mode when its gateway says so (`Telemetry.control`, from the radios file):
the vehicle's configuration lives in one place. Everything on the ground (pure pursuit), the mode
machine, the take-off and landing references, the tracking guard and the fault landings are the
same in both modes; only the setpoint and the estimator's input differ:

- following a reference (take-off, flight, landing, a fault landing, a held hover): the reference
  as the setpoint, its acceleration taken `ACCEL_LEAD_S` ahead; the executor's Kalman filter predicts with the reference's acceleration
  (the onboard controller feeds it forward), or none while the link is lost (the vehicle then holds
  its last setpoint);
- emergency descent (poses stale in the air, `faults.py`): the executor's dead-reckoned state, braked
  horizontally and steered down at the descent speed, *is* the setpoint: without motion capture the
  onboard estimate drifts on the IMU alone (slowly: centimetres over a descent), its controller
  follows the descending setpoint in that frame, and the motors stop on the same predicted-touchdown
  rule as in offboard mode.
"""

from __future__ import annotations

from common.bus.messages import PositionSetpoint, Telemetry
from common.flight.estimator import Estimate, PoseEstimator
from common.flight.reference import RefSample
from services.executor.faults import FaultParams

ACCEL_LEAD_S = 0.1
"""The acceleration feed-forward is taken this far ahead on the reference: the vehicle's attitude
loop realises a commanded tilt about its time constant later (docs/control.md: 0.10 s assumed),
so at the reference's corners (the parabolic blends) it arrives on time instead of late."""


def onboard(tel: Telemetry | None) -> bool:
    """The vehicle is in onboard control mode (its gateway's word; offboard until it has spoken)."""
    return tel is not None and tel.control == "onboard"


def follow(ref: RefSample, ahead: RefSample | None, estimator: PoseEstimator, now: float,
           link_ok: bool) -> PositionSetpoint:
    """The full-state setpoint of reference `ref`, with the acceleration of `ahead` (the reference
    `ACCEL_LEAD_S` later, or `ref`); the estimator predicts with `ref`'s acceleration."""
    estimator.set_input((ref.ax, ref.ay, ref.az) if link_ok else (0.0, 0.0, 0.0), now)
    acc = ahead or ref
    return PositionSetpoint(x=ref.x, y=ref.y, z=ref.z, vx=ref.vx, vy=ref.vy, vz=ref.vz, ax=acc.ax, ay=acc.ay,
                            az=acc.az, yaw=ref.yaw, yaw_rate=ref.yaw_rate)


def descent(est: Estimate, accel: float, estimator: PoseEstimator, faults: FaultParams, now: float) -> PositionSetpoint:
    """One step of the emergency descent: vertical acceleration `accel` (`FaultParams.descent_accel_cmd`),
    the horizontal speed braked (`FaultParams.descent_brake`); the dead-reckoned state as the setpoint."""
    ax, ay = faults.descent_brake(est.vx, est.vy)
    estimator.set_input((ax, ay, accel), now)
    return PositionSetpoint(x=est.x, y=est.y, z=est.z, vx=est.vx, vy=est.vy, vz=est.vz, ax=ax, ay=ay, az=accel,
                            yaw=est.yaw)
