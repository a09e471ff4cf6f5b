"""Each fault handling disabled, its test fails: the table of docs/reliability.md, reproduced.

    python -m tests.check_handlers [--only TEXT ...] [--ref REV] [--list] [--jobs 1]

For every handling in `HANDLINGS`, a copy of the repository (the working tree without .venv, .git
and outputs; or `--ref REV` exported with `git archive`) gets a small textual change that disables
it, and that handling's test runs in the copy with this repository's venv (the copy first on
PYTHONPATH and as the working directory, so the tests and every service process they start import
the copy). Each test also runs once in an unchanged copy. The table says, per handling, the
disabling change, the test, its result with the handling (it must pass) and without (it must fail,
or pass where the table says so: defence in depth).

A change names its file and the exact text it replaces, which must occur exactly once: after a
refactor that moves or rewrites the text, the script stops before running anything and says which
target is gone (`tests/test_check_handlers.py` checks the same in `make test`, so the refactor fails
there first). Not collected by pytest (not a `test_*.py` file); fault tests start zenoh and a fleet:
run it under `flock /tmp/fleet-heavy.lock` on a shared machine. Exit 0 when every row is as expected.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SKIP = {".venv", ".git", "out", ".fleet", "__pycache__", ".pytest_cache", ".ruff_cache", ".import_linter_cache",
        ".mypy_cache"}
"""Top-level and nested names left out of the copy (environments, caches, outputs)."""
TEST_TIMEOUT_S = 900.0


@dataclass(frozen=True)
class Edit:
    """Replace `old` (exactly one occurrence) by `new` in `path` (relative to the repository)."""

    path: str
    old: str
    new: str


@dataclass(frozen=True)
class Handling:
    name: str
    change: str
    """The disabling change, in words (for the table)."""
    edits: tuple[Edit, ...]
    test: str
    """pytest node id, relative to the repository."""
    disabled: str = "fail"
    """What the test does with the handling disabled: "fail", or "pass" where another handling
    also covers the fault (defence in depth)."""


HANDLINGS: tuple[Handling, ...] = (
    Handling(
        "prediction bridging 0.3 s of motion-capture loss",
        "estimator `stale_std` 0.25 m -> 0.10 m (stale after 0.25 s)",
        (Edit("common/flight/estimator.py", "    stale_std: float = 0.25\n", "    stale_std: float = 0.10\n"),),
        "tests/test_faults_mocap.py::test_a_short_dropout_is_flown_through_a_long_one_lands_the_vehicle_and_the_others_fly_on"),
    Handling(
        "emergency landing on a stale pose in the air",
        "executor: a stale pose in the air no longer requests EMERGENCY_LANDING",
        (Edit("services/executor/vehicle_controller.py",
              "            if est.stale:\n                vertical = ",
              "            if False:\n                vertical = "),),
        "tests/test_faults_mocap.py::test_a_short_dropout_is_flown_through_a_long_one_lands_the_vehicle_and_the_others_fly_on"),
    Handling(
        "the simulated firmware's commander watchdog",
        "supervisor: watchdog warning and timeout never raised",
        (Edit("services/sim/crazyflie/firmware/supervisor.py",
              "        c.wdt_warning = inp.setpoint_age_s > WDT_WARNING_S\n", "        c.wdt_warning = False\n"),
         Edit("services/sim/crazyflie/firmware/supervisor.py",
              "        c.wdt_timeout = inp.setpoint_age_s > WDT_TIMEOUT_S\n", "        c.wdt_timeout = False\n")),
        "tests/test_faults_radio.py::test_firmware_levels_at_half_a_second_cuts_at_two_and_the_gateway_reports_the_loss"),
    Handling(
        "the gateway's link timeout",
        "gateway `LinkHealth.check` never reports `link_lost`",
        (Edit("services/radio_gateway/health.py",
              "        if not self.link_ok or now - self._since <= self.timeout_s:\n            return []\n",
              "        if True:\n            return []\n"),),
        "tests/test_faults_radio.py::test_firmware_levels_at_half_a_second_cuts_at_two_and_the_gateway_reports_the_loss"),
    Handling(
        "the executor's lost-link landing",
        "executor `FaultMonitor.link_lost` always False",
        (Edit("services/executor/faults.py",
              "    def link_lost(self, now: float) -> bool:\n",
              "    def link_lost(self, now: float) -> bool:\n        return False  # disabled\n"),),
        "tests/test_faults_radio.py::test_a_link_lost_mid_flight_lands_the_vehicle_and_one_lost_while_driving_comes_back"),
    Handling(
        "no yield when the plan leaves the held vehicle",
        "executor: `yield_to` yields whatever its plan does next",
        (Edit("services/executor/vehicle_controller.py",
              "        if not any(gap(*p) < now_gap - YIELD_APPROACH for ahead, p in places if ahead >= 0.0):\n",
              "        if False:\n"),),
        "tests/test_tracking_guard.py::test_a_vehicle_whose_plan_leaves_a_held_one_beside_it_goes_on"),
    Handling(
        "a vehicle held by a fault that cleared brought back",
        "mission: no vehicle comes back (`REJOINS` 0)",
        (Edit("services/mission/rejoin.py", "REJOINS = 3\n", "REJOINS = 0\n"),),
        "tests/test_faults_radio.py::test_a_link_lost_mid_flight_lands_the_vehicle_and_one_lost_while_driving_comes_back"),
    Handling(
        "a vehicle come down blind in its take-off brought back",
        "executor: every emergency descent ends done (none held where it came down)",
        (Edit("services/executor/vehicle_controller.py",
              "        if (column is None or est.stale or self._abort",
              "        if (True or column is None or est.stale or self._abort"),),
        "tests/test_faults_mocap.py::test_a_dropout_in_a_take_off_lands_the_vehicle_on_its_spot_and_the_mission_brings_it_back"),
    Handling(
        "a vehicle the guard held late on its way brought back",
        "executor: every vehicle the guard holds for its own tracking counts as off its way",
        (Edit("services/executor/vehicle_controller.py", "        return off <= reach, f\"; {off:.3f}",
              "        return False, f\"; {off:.3f}"),),
        "tests/test_fault_replan.py::test_a_vehicle_held_by_wind_and_one_stopped_alone_leave_the_others_flying_on"),
    Handling(
        "a vehicle done where a fault put it down refusing its mission's replans",
        "executor: a vehicle done takes any plan of its running mission (`load`)",
        (Edit("services/executor/vehicle_controller.py",
              "        if self.mode == Mode.DONE and old is not None and self.t0 is not None and (off := self._off_plan(",
              "        if False and (off := self._off_plan("),),
        "tests/test_rejoin.py::test_a_vehicle_that_came_down_blind_in_its_take_off_or_landing_is_held_there_and_taken_back"),
    Handling(
        "a blind descent with its poses back landing over its column's foot",
        "executor: it lands where it is when its poses are back (no `over`)",
        (Edit("services/executor/vehicle_controller.py", "                over = self._back_over(est)\n",
              "                over = None\n"),),
        "tests/test_rejoin.py::test_a_vehicle_that_came_down_blind_in_its_take_off_or_landing_is_held_there_and_taken_back"),
    Handling(
        "the executor's low-battery landing",
        "executor: `low` always False in its supervision (the event still comes at the planned landing)",
        (Edit("services/executor/vehicle_controller.py",
              "        low = self.faults.low_battery(self.charge_used_ah, now)\n", "        low = False\n"),),
        "tests/test_faults_battery.py::test_low_battery_mid_flight_lands_at_the_nearest_safe_node_and_the_others_fly_on"),
    Handling(
        "the executor's `low_battery` event",
        "executor: a landing never reported as `low_battery`",
        (Edit("services/executor/service.py",
              "            if ctl.faults.low_battery(ctl.charge_used_ah, now):\n                kind = \"low_battery\"\n",
              "            if False:\n                kind = \"low_battery\"\n"),),
        "tests/test_faults_battery.py::test_low_battery_mid_flight_lands_at_the_nearest_safe_node_and_the_others_fly_on"),
    Handling(
        "ownership frozen while the router is lost",
        "executor: a change of the live executors applied even without the router",
        (Edit("services/executor/service.py",
              "        if self._router_lost_at is None and self.session.info.routers_zid():\n",
              "        if True:\n"),),
        "tests/test_faults_router.py::test_router_restart_mid_flight_aborts_the_mission_cleanly"),
    Handling(
        "executors abort their missions when they lose the router",
        "executor: nothing aborted on losing the router",
        (Edit("services/executor/service.py",
              "                for vid, ctl in self.controllers.items():\n"
              "                    if ctl.t0 is not None:  # started (or due to start): its timing is gone\n",
              "                for vid, ctl in {}.items():\n"
              "                    if ctl.t0 is not None:  # started (or due to start): its timing is gone\n"),),
        "tests/test_faults_router.py::test_router_restart_mid_flight_aborts_the_mission_cleanly"),
    Handling(
        "the runner's lost-contact check",
        "mission client: `_check_contact` not called",
        (Edit("services/mission/client.py", "                self._check_contact(now)\n", "                pass\n"),),
        "tests/test_faults_router.py::test_router_restart_mid_flight_aborts_the_mission_cleanly",
        disabled="pass"),
    Handling(
        "the runner's planner liveliness check",
        "mission client: no check that a planner is alive",
        (Edit("services/mission/client.py", "        if not (await self.watch_alive(\"planner\")).instances:\n",
              "        if False:\n"),),
        "tests/test_faults_planner.py::test_a_mission_without_a_reachable_planner_fails_within_seconds"),
    Handling(
        "the runner's `QueryError` handling",
        "mission client: `QueryError` from the plan query not caught",
        (Edit("services/mission/client.py", "        except QueryError as exc:\n",
              "        except ZeroDivisionError as exc:\n"),),
        "tests/test_faults_planner.py::test_a_mission_without_a_reachable_planner_fails_within_seconds"),
    Handling(
        "take-over of a dead executor's vehicles",
        "executor: `VehicleOwnership.reassign` never takes a vehicle",
        (Edit("services/executor/takeover.py",
              "            if self.mine(vid) and not held:\n                self._take(vid)\n",
              "            if False:\n                self._take(vid)\n"),),
        "tests/test_fleet_e2e.py::test_executor_killed_mid_flight_its_vehicles_still_arrive"),
    Handling(
        "median hover thrust of the gateway's blind landing",
        "gateway: the last setpoint's thrust instead of the median",
        (Edit("services/radio_gateway/vehicle.py", "        hover = statistics.median(self._thrusts)\n",
              "        hover = self._thrusts[-1]\n"),),
        "tests/test_faults_blind_landing.py::test_a_blind_safety_landing_from_any_moment_of_the_flight_touches_down_gently"),
    Handling(
        "refusing stop or wheels during the safety landing",
        "gateway: no `while_landing` refusal",
        (Edit("services/radio_gateway/vehicle.py", "        if self.mode == Drive.LANDING and not flight:\n",
              "        if False:\n"),),
        "tests/test_faults_blind_landing.py::test_a_stop_or_wheel_command_does_not_end_the_safety_landing_in_the_air"),
    Handling(
        "landing in place once poses are back in an emergency descent",
        "executor: the blind descent goes on with poses back, motors off at the predicted time once it seems at rest",
        (Edit("services/executor/vehicle_controller.py",
              "        if not est.stale and not on_board:  # (a blind",
              "        if False:  # (a blind"),),
        "tests/test_closed_loop.py::test_an_emergency_descent_on_a_slow_loop_with_poses_coming_and_going_lands_gently",
        disabled="pass"),
    Handling(
        "a take-off left among the vehicles on the ground",
        "tracking guard: a take-off's height lag is never judged",
        (Edit("services/executor/vehicle_controller.py",
              "if height < self.model.height < planned - f.guard_burst * margin and now",
              "if False and now"),),
        "tests/test_tracking_guard.py::test_a_take_off_left_among_the_vehicles_on_the_ground_is_held"),
    Handling(
        "the flight LQR's attitude over the time its commands held",
        "flight LQR: the attitude propagated one period per command, however long it held",
        (Edit("common/flight/lqr.py", "            if late > 0.0:  # the last command held",
              "            if late > 99.0:  # the last command held"),),
        "tests/test_controllers.py::test_on_a_slow_loop_the_propagated_attitude_is_the_vehicles"),
    Handling(
        "the blind descent's learned lift error",
        "executor: the blind descent's thrust as the model says, whatever the estimator learned of its error",
        (Edit("services/executor/vehicle_controller.py", "        k = max(self.estimator.lift_error, 0.0)  #",
              "        k = 0.0  #"),),
        "tests/test_closed_loop.py::test_a_vehicle_stronger_or_weaker_than_its_model_that_loses_its_poses_in_the_climb_lands_blind"),
    Handling(
        "poses back during the gateway's blind descent",
        "gateway: once blind, the safety landing descends open loop to its end",
        (Edit("services/radio_gateway/landing.py", "(self._open_loop is None or est.vz > _CLIMBING)",
              "self._open_loop is None"),),
        "tests/test_gateway_landing.py::test_poses_back_during_a_blind_descent_that_climbs_land_it_in_place"),
    Handling(
        "the reflex's allowance for a held vehicle's time unseen",
        "executor: `yield_to` ignores how long the held vehicle went unseen",
        (Edit("services/executor/vehicle_controller.py", "        unseen = min(max(unseen_s, 0.0) *",
              "        unseen = 0.0 * min(max(unseen_s, 0.0) *"),),
        "tests/test_tracking_guard.py::test_a_vehicle_held_unseen_for_a_while_is_given_the_way_it_may_have_gone"),
    Handling(
        "the reflex to an executor's own held vehicle at once",
        "executor: the reflex waits for the event to come back through the router",
        (Edit("services/executor/service.py", "        self._reflex(event, event.t)\n", ""),
         Edit("services/executor/service.py", "        if event.vid not in self.controllers:\n", "        if True:\n")),
        "tests/test_tracking_guard.py::test_the_reflex_to_a_vehicle_its_own_executor_holds_comes_in_the_same_cycle"),
    Handling(
        "the proximity stop counting the hold's own stop",
        "proximity stop: a closing counted as braking at 2 m/s^2 alone",
        (Edit("services/executor/proximity.py", "    hold_s: float = 0.12\n", "    hold_s: float = 0.0\n"),),
        "tests/test_proximity.py::test_a_vehicle_stopped_short_comes_to_rest_within_the_way_the_stop_counted[fly-0.3]"),
    Handling(
        "the proximity stop judging a mover on its way bent as its plan bends",
        "executor: a mover judged on straight lines (`VehicleController.bend` gives none)",
        (Edit("services/executor/vehicle_controller.py",
              "        if self._seen is None or self._seen[2] is None or self._active is None or self._hover_ref is not None:\n",
              "        if True:\n"),),
        "tests/test_proximity.py::test_a_flyer_on_time_into_its_hover_beside_a_body_does_not_stop_short"),
    Handling(
        "an old attitude resent levelled",
        "gateway: the owner's last attitude resent as it was until the command is stale",
        (Edit("services/radio_gateway/vehicle.py",
              "        if self.onboard or sp is None or now - self.cmd_at <= self.params.level_s or sp.thrust < FIRMWARE_MIN_THRUST:\n",
              "        if True:\n"),),
        "tests/test_gateway_level.py::test_a_held_flyer_whose_executor_falls_silent_does_not_swing_back"),
    Handling(
        "the flight controller leading its commands' actuation",
        "executor: the flight LQR on the state and reference of its tick (no lead)",
        (Edit("services/executor/vehicle_controller.py", "ACTUATION_S = 0.05\n", "ACTUATION_S = 0.0\n"),),
        "tests/test_closed_loop.py::test_a_flyer_whose_commands_act_late_holds_its_height_when_its_controller_leads"),
    Handling(
        "only steady thrust teaching the lift error on a late loop",
        "estimator: every thrust command teaches the lift error, however late the loop",
        (Edit("common/flight/estimator.py", "LIFT_LATE_S = 0.05\n", "LIFT_LATE_S = math.inf\n"),),
        "tests/test_closed_loop.py::test_a_flyer_on_a_late_loop_holds_its_height_when_only_steady_thrust_teaches_the_lift_error"),
    Handling(
        "a vehicle taken over given back only to steady commands",
        "gateway: a vehicle taken over for stale commands given back to the first fresh one",
        (Edit("common/deploy/radios.py", "    resume_s: NonNegative = 0.1\n", "    resume_s: NonNegative = 0.0\n"),),
        "tests/test_gateway_landing.py::test_an_executor_starved_in_bursts_gets_its_vehicle_back_only_once_its_commands_come_steadily"),
    Handling(
        "held hovering vehicles keeping apart",
        "executor: a vehicle held hovering stays where it began to hover, however near another body",
        (Edit("services/executor/proximity.py", "    standoff: float = 0.04\n", "    standoff: float = 0.0\n"),),
        "tests/test_proximity.py::test_two_vehicles_held_hovering_near_each_other_move_apart[True]"),
    Handling(
        "a held flyer thrown off its point kept off its way back through a body",
        "executor: a held flyer flies back to its hover point whatever is in the way",
        (Edit("services/executor/vehicle_controller.py", "ASTRAY_M = 0.05\n", "ASTRAY_M = math.inf\n"),),
        "tests/test_proximity.py::test_a_held_flyer_blown_off_its_hover_point_does_not_fly_back_through_a_body[True]"),
    Handling(
        "a proximity stop judged on the plans of two vehicles keeping to them",
        "executor: a proximity stop judges from the motion capture alone",
        (Edit("services/executor/service.py", "            if self._plans_keep_apart(closing, radius, height, now):\n",
              "            if False:\n"),),
        "tests/test_plan_clearance.py::test_two_flyers_on_plans_that_cross_at_their_margin_go_on[True]"),
    Handling(
        "a proximity stop for a vehicle keeping to its plan paused on the mission's clock",
        "executor: a proximity stop holds the vehicle for the rest of the mission (the others planned around it)",
        (Edit("services/executor/service.py", "            if self._may_pause(closing.mover, closing.other, now):\n",
              "            if False:\n"),),
        "tests/test_proximity_pause.py::test_a_flyer_heading_into_one_blown_off_its_plan_pauses_and_goes_on"),
    Handling(
        "a flyer the guard would hold for its own tracking pauses the mission first",
        "executor: the guard holds a flyer off its plan at once (the others planned around it)",
        (Edit("services/executor/vehicle_controller.py",
              "        if error <= f.guard_burst * margin and self._pause_for_tracking(why, now):\n",
              "        if False:\n"),),
        "tests/test_proximity_pause.py::test_a_flyer_blown_off_its_plan_pauses_the_mission_and_goes_on"),
    Handling(
        "a vehicle going on from a pause brings the clock back to full pace over a second",
        "executor: the clock a pause stood runs at full pace again at once",
        (Edit("services/executor/vehicle_controller.py", "            ramp = (now - self._resumed) / RESUME_S\n",
              "            ramp = 1.0\n"),),
        "tests/test_proximity_pause.py::test_a_flyer_going_on_from_a_pause_keeps_near_its_reference_as_the_clock_comes_back[ramped]"),
    Handling(
        "a stranded vehicle's goal asked for again",
        "mission: a goal a replan left out of reach stays so for the mission",
        (Edit("services/mission/runner.py",
              "        return {v: g for v, g in self.stranded.items() if v not in left and v not in self.left}\n",
              "        return {}\n"),),
        "tests/test_replan.py::test_a_stranded_vehicle_goes_on_to_its_goal_once_a_later_replan_finds_it_in_reach"),
    Handling(
        "the flight LQR's gain following the loop's period",
        "flight LQR: the 100 Hz gain whatever the loop's period",
        (Edit("common/flight/lqr.py", "GAIN_PERIODS = (0.01, 0.02, 0.04, 0.08, 0.16, 0.32)\n", "GAIN_PERIODS = (0.01,)\n"),),
        "tests/test_controllers.py::test_on_a_slow_loop_a_vehicle_holding_a_point_does_not_swing"),
    Handling(
        "re-stopping on a status that shows the motors running",
        "gateway: no `motors_restopped`",
        (Edit("services/radio_gateway/vehicle.py",
              "        if (fresh and after_stops and status.flags & crtp.FLAG_MOTORS",
              "        if (False and fresh and after_stops and status.flags & crtp.FLAG_MOTORS"),),
        "tests/test_gateway_scheduler.py::test_motors_reported_running_after_the_stops_were_lost_are_stopped_again"),
    Handling(
        "the simulator taking every waiting setpoint at once",
        "simulated Crazyflie: one datagram per read of its socket",
        (Edit("services/sim/crazyflie/endpoint.py", "            self.datagram_received(data, addr, at)\n",
              "            self.datagram_received(data, addr, at)\n            return  # disabled\n"),),
        "tests/test_simcf.py::test_a_busy_simulator_takes_every_waiting_setpoint_at_once_at_the_time_it_arrived"),
    Handling(
        "the simulator's setpoints at their kernel receive times",
        "simulated Crazyflie: every datagram at the time it is read",
        (Edit("services/sim/crazyflie/endpoint.py", "                    at = min(sec + nsec * 1e-9, now)\n",
              "                    at = now\n"),),
        "tests/test_simcf.py::test_a_busy_simulator_takes_every_waiting_setpoint_at_once_at_the_time_it_arrived"),
    Handling(
        "the estimator's command history for late poses",
        "estimator: a pose predicted to with the last command only",
        (Edit("common/flight/estimator.py", "        if until <= start:\n            return self._accel\n",
              "        if True:\n            return self._accel\n"),),
        "tests/test_estimator.py::test_late_poses_and_changing_commands_keep_the_estimate_on_the_truth"),
    Handling(
        "the estimator's floor for its dead reckoning",
        "estimator: the dead reckoning goes through the floor",
        (Edit("common/flight/estimator.py", "        if self.floor is not None and x[2] < self.floor:\n",
              "        if False:\n"),),
        "tests/test_estimator.py::test_the_dead_reckoning_stops_at_the_floor_it_is_given"),
    Handling(
        "the estimator's floor for its own state",
        "estimator: the filter's state goes through the floor (its dead reckoning still stops there)",
        (Edit("common/flight/estimator.py",
              "        if self.floor is not None and x[4] < self.floor:  # the filter's state too",
              "        if False:  # the filter's state too"),),
        "tests/test_estimator.py::test_poses_on_the_floor_after_a_fall_are_taken_not_rejected"),
    Handling(
        "the estimator's restart after rejected poses spanning 0.08 s",
        "estimator: the restart after 10 rejected poses, however long they took",
        (Edit("common/flight/estimator.py", "    reacquire_after: int = 3\n    reacquire_s: float = 0.08\n",
              "    reacquire_after: int = 10\n    reacquire_s: float = 0.0\n"),),
        "tests/test_estimator.py::test_a_prediction_gone_wrong_is_reacquired_within_a_tenth_of_a_second_also_on_few_poses"),
    Handling(
        "the estimator's input is the thrust commanded",
        "flight LQR: the expected acceleration less the integrator's bias of the moment",
        (Edit("common/flight/lqr.py", "by * c - d * est.vy, accel - d * est.vz)", "by * c - d * est.vy, accel - self.accel_bias() - d * est.vz)"),),
        "tests/test_controllers.py::test_the_expected_acceleration_is_the_commands_also_with_the_integrator_wound_up"),
    Handling(
        "the landing in place settling on the ground",
        "landing in place: no thrust cap near the ground with the descent's reference at its end",
        (Edit("common/flight/landing.py",
              "        if z_ref <= descent_end(self.touchdown_height, ground) and est.z - ground < SETTLE_HEIGHT:",
              "        if False:"),),
        "tests/test_closed_loop.py::test_an_emergency_descent_on_a_slow_loop_with_poses_coming_and_going_lands_gently",
        disabled="pass"),
    Handling(
        "the landing in place descending afresh after a bounce",
        "landing in place: the descent's reference stays where its time put it",
        (Edit("common/flight/landing.py", "        if est.z - z_ref > REANCHOR_GAP and", "        if False and"),),
        "tests/test_gateway_landing.py::test_a_vehicle_thrown_up_near_the_ground_descends_afresh_and_touches_down_gently"),
    Handling(
        "a stale-command landing whose commands come back is no mission fault",
        "mission client: every `stale_cmd_landing` a fault at once",
        (Edit("services/mission/client.py",
              "        if event.kind == \"stale_cmd_landing\":  # a fault only if the commands do not come back\n",
              "        if False:  # a fault only if the commands do not come back\n"),),
        "tests/test_stale_commands.py::test_commands_back_within_the_grace_are_no_fault"),
    Handling(
        "a safe landing from the node's height",
        "executor `_MIN_DESCENT` 0.01 -> 0",
        (Edit("services/executor/faults.py", "_MIN_DESCENT = 0.01\n", "_MIN_DESCENT = 0.0\n"),),
        "tests/test_faults_radio.py::test_a_safe_landing_from_the_ground_is_still_a_trajectory"),
    Handling(
        "the turn at a corner budgeted in the plan",
        "SIPP leaves a corner as soon as it arrives (no wait for the turn onto the next road)",
        (Edit("services/planner/sipp/search.py",
              "            ready = t + turn_time(arrived_along, heading[e], turn_rate) if turn_rate else t",
              "            ready = t"),),
        "tests/test_sipp.py::test_a_path_waits_at_each_corner_for_the_turn_onto_its_next_road[3.0]"),
    Handling(
        "the turn in a wait at a corner",
        "executor: at a node where its plan waits a driving vehicle holds instead of turning to its next road",
        (Edit("services/executor/vehicle_controller.py", "            turn = self._turn_in_wait(est, ref)\n",
              "            turn = None\n"),),
        "tests/test_closed_loop.py::test_at_a_corner_it_turns_in_the_wait_its_plan_budgets[budgeted]"),
    Handling(
        "driving tail first where a path doubles back",
        "pure pursuit never changes the way it drives (it turns round instead)",
        (Edit("services/executor/pure_pursuit.py", "        if abs(err) > flip_beyond:\n",
              "        if False:\n"),),
        "tests/test_controllers.py::test_a_path_that_doubles_back_at_a_node_is_driven_within_the_margin"),
    Handling(
        "a burst of faults replanned once, after the replan under way",
        "mission runner: every fault's replan runs, one after another",
        (Edit("services/mission/runner.py", "        if ticket < self._fault_replans:\n            self.replans_skipped",
              "        if False:\n            self.replans_skipped"),),
        "tests/test_replan_burst.py::test_a_burst_of_holds_during_a_replan_is_replanned_once_after_it"),
    Handling(
        "a failed replan left to the one queued behind it",
        "mission runner: any failed replan is the mission's fault",
        (Edit("services/mission/runner.py", "        if error and ticket < self._fault_replans:\n",
              "        if error and False:\n"),),
        "tests/test_replan_burst.py::test_a_burst_of_holds_during_a_replan_is_replanned_once_after_it"),
    Handling(
        "the reflex to a vehicle coming down",
        "executor: `yield_to` treats a descending vehicle as one held where it was",
        (Edit("services/executor/vehicle_controller.py",
              "                       (z - pos[2] if descending else abs(z - pos[2])) - reach_z)\n",
              "                       abs(z - pos[2]) - reach_z)\n"),),
        "tests/test_tracking_guard.py::test_a_vehicle_whose_plan_passes_under_one_coming_down_holds_too"),
    Handling(
        "the bodies judged at every instant of the ground truth",
        "mission: the bodies judged once every 0.1 s",
        (Edit("services/mission/separation.py", "        if truth.t > self._instant + SAME_INSTANT_S:\n",
              "        if truth.t > self._instant + 0.1:\n"),),
        "tests/test_separation.py::test_a_brush_shorter_than_a_tenth_of_a_second_is_a_contact"),
    Handling(
        "a fault landing keeps off another vehicle's column",
        "executor: a fault landing comes down on the nearest landing node, whoever stands there",
        (Edit("services/executor/faults.py", "    free = [s for s in nodes if clear(",
              "    free = nodes or [s for s in nodes if clear("),),
        "tests/test_closed_loop.py::test_an_abort_lands_on_the_nearest_landing_node_clear_of_the_vehicles_standing_there"),
    Handling(
        "a fault landing flies round a body hovering in its way",
        "executor: a fault landing flies level to its node whatever hovers in between",
        (Edit("services/executor/faults.py", "            and not any(in_way(pos, spot, b, model) for b in bodies))",
              ")"),),
        "tests/test_fault_landing.py::test_a_fault_landing_flies_round_no_body_hovering_in_its_way"),
    Handling(
        "a fault landing's flight stops short of a body",
        "executor: a fault landing's flight to its node goes on whatever it heads into",
        (Edit("services/executor/vehicle_controller.py",
              "        if self._landing_flight():\n            self._landing_paused = why\n            return True\n", ""),),
        "tests/test_closed_loop.py::test_an_aborted_vehicle_whose_flight_to_its_node_heads_into_a_body_hovers_and_chooses_again"),
    Handling(
        "a landing's descent nothing stops counted as coming closer",
        "executor: a body coming closer is counted as standing, a fault landing's descent too",
        (Edit("services/executor/proximity.py", "            counted |= np.isin(j, unstopped)\n", "            pass\n"),),
        "tests/test_proximity.py::test_a_vehicle_driving_in_under_a_fault_landings_descent_stops_short"),
    Handling(
        "an emergency descent with its poses back comes down beside a body below it",
        "executor: an emergency descent with its poses back lands where it is, whatever is below",
        (Edit("services/executor/vehicle_controller.py",
              "                if (beside := self._beside_a_body(est, over)) is not None:\n",
              "                if False:\n"),),
        "tests/test_fault_landing.py::"
        "test_an_emergency_descent_with_its_poses_back_comes_down_beside_a_body_in_its_column_and_says_where[parked_below]"),
    Handling(
        "an emergency descent back over its take-off's foot comes down beside a body there",
        "executor: an emergency descent with its poses back lands over its take-off's foot, whatever is there",
        (Edit("services/executor/vehicle_controller.py",
              "                if (beside := self._beside_a_body(est, over)) is not None:\n",
              "                if over is None and (beside := self._beside_a_body(est, over)) is not None:\n"),),
        "tests/test_fault_landing.py::"
        "test_an_emergency_descent_with_its_poses_back_comes_down_beside_a_body_in_its_column_and_says_where"
        "[parked_on_its_take_off_foot]"),
    Handling(
        "a planned landing a fault let go on lands elsewhere with a body below it",
        "executor: a planned landing under way at an abort comes down on its node, whatever stands there",
        (Edit("services/executor/vehicle_controller.py", "                    and self._planned_landing_blocked(est, ref)):\n",
              "                    and False):\n"),),
        "tests/test_closed_loop.py::test_an_abort_in_a_planned_landing_lands_elsewhere_with_a_body_below_it[rolls_in_later]"),
    Handling(
        "a vehicle in the air a replan cannot place held where it is",
        "mission runner: only a vehicle on the ground the replan cannot place is stopped alone; one in the air fails the mission",
        (Edit("services/mission/runner.py", "state.mode not in GROUND_MODES | AIR_MODES", "state.mode not in GROUND_MODES"),),
        "tests/test_replan_burst.py::"
        "test_the_vehicles_a_replan_cannot_place_are_held_or_stopped_where_they_are_at_once_and_the_others_go_on"),
    Handling(
        "every vehicle a replan cannot place stopped at once",
        "mission runner: only the first vehicle a replan names is stopped; the next replan names the next",
        (Edit("services/mission/runner.py", "vid for vid in blocked if self._stop_where_it_is", "vid for vid in blocked[:1] if self._stop_where_it_is"),),
        "tests/test_replan_burst.py::"
        "test_the_vehicles_a_replan_cannot_place_are_held_or_stopped_where_they_are_at_once_and_the_others_go_on"),
    Handling(
        "a jam of cars a replan cannot place stopped car after car",
        "mission runner: a fault's replan stops three vehicles at most (the limit before), then the mission ends",
        (Edit("services/mission/runner.py", "        while error and self._stop_blocked(error):",
              "        while error and len(self.left) < 4 and self._stop_blocked(error):"),),
        "tests/test_replan_burst.py::test_a_jam_of_cars_a_replan_cannot_place_one_after_another_is_stopped_car_after_car"),
    Handling(
        "a replan names every vehicle no order can place",
        "SIPP replan: the priority orders are tried until one fails for good; it names the vehicle that failed last",
        (Edit("services/planner/sipp/replan.py", "    if shut := [leg for leg in order if", "    if False and [leg for leg in order if"),),
        "tests/test_replan.py::test_a_replan_names_every_vehicle_whose_switch_node_a_body_claims_at_once"),
    Handling(
        "a vehicle its mission holds hovers where it is",
        "executor: a mission's hold (`MissionAbort.hold`) aborts the vehicle: it lands",
        (Edit("services/executor/service.py", "        if abort.hold:", "        if False:"),),
        "tests/test_tracking_guard.py::test_a_vehicle_its_mission_holds_in_the_air_hovers_where_it_is_and_may_come_back[guard]"),
    Handling(
        "a planned landing sent elsewhere says where",
        "executor: a landing chosen again while the vehicle stays in its landing is not reported",
        (Edit("services/executor/service.py",
              "        if prev != mode or (mode == Mode.LANDING and self._landing_moved(vid, ctl)):",
              "        if prev != mode:"),),
        "tests/test_fault_landing.py::test_a_planned_landing_a_lost_link_sends_elsewhere_is_reported_where_it_goes"),
    Handling(
        "an emergency descent coming down beside a body says where",
        "executor: an emergency descent that comes down beside a body in its column reports nothing of it",
        (Edit("services/executor/service.py", "            if aside is not None:\n", "            if False:\n"),),
        "tests/test_fault_landing.py::"
        "test_an_emergency_descent_with_its_poses_back_comes_down_beside_a_body_in_its_column_and_says_where[parked_below]"),
    Handling(
        "a replan that ran out of its time asked again",
        "mission runner: a replan whose planner ran out of its time limit fails the mission",
        (Edit("services/mission/runner.py", "            if not reply.ok and reply.timed_out and k + 1 < len(REPLAN_TIME_LIMITS_S):",
              "            if False:"),),
        "tests/test_replan_burst.py::test_a_replan_that_ran_out_of_its_time_is_asked_again_with_more"),
    Handling(
        "another executor's fault landing kept off",
        "executor: another executor's announced fault landing is not counted",
        (Edit("services/executor/service.py",
              "        return seen + [step.pos for step in mine if step is not None] + theirs\n",
              "        return seen + [step.pos for step in mine if step is not None]\n"),),
        "tests/test_fault_landing.py::test_another_executors_fault_landing_is_heard_and_its_node_passed_over"),
    Handling(
        "two fault landings of an abort part",
        "executor: a fault landing keeps its node when another executor's chose it at the same moment",
        (Edit("services/executor/vehicle_controller.py", "            self._choose_again = True\n",
              "            self._choose_again = False\n"),),
        "tests/test_fault_landing.py::test_two_fault_landings_of_an_abort_that_chose_one_node_part[cf1-l1]"),
    Handling(
        "a fault landing with nowhere clear goes straight down or hovers",
        "executor: with a body below every node of its plan, a fault landing takes the nearest all the same",
        (Edit("services/executor/faults.py", "    if free:\n", "    if free or nodes:\n"),
         Edit("services/executor/faults.py", "        target = min(free, key=", "        target = min(free or nodes, key=")),
        "tests/test_fault_landing.py::test_a_fault_landing_with_nowhere_clear_hovers_until_the_vehicle_below_drives_off"),
    Handling(
        "vehicles whose prefixes end at one node placed the last to arrive first",
        "planner: a replan's first order places the vehicles by their switch times alone",
        (Edit("services/planner/sipp/replan.py",
              "(ahead.get(leg.vid, len(ahead)), together[leg.start], -leg.depart, leg.vid)",
              "(ahead.get(leg.vid, len(ahead)), leg.depart, leg.vid)"),),
        "tests/test_replan.py::test_a_soaks_replan_whose_first_order_met_head_on_is_valid_on_its_first_order"),
    Handling(
        "a replan's vehicle placed first plans against the last steps coming to its switch node",
        "planner: a vehicle placed before another searches without the other's last step",
        (Edit("services/planner/sipp/replan.py", "    coming = _coming_near(graph, order)\n",
              "    coming: dict[int, list[tuple[Leg, int]]] = {}\n"),),
        "tests/test_replan.py::test_a_vehicle_placed_before_another_plans_against_its_last_step"),
    Handling(
        "a fault landing off the graph keeps out of the map's obstacles",
        "executor: a fault landing comes down straight or beside it whatever the map has there",
        (Edit("services/executor/faults.py", "    if ground is None or not spots:\n", "    if True:\n"),),
        "tests/test_fault_landing.py::test_a_landing_off_the_graph_keeps_out_of_the_maps_obstacles_and_no_fly_zones"),
    Handling(
        "a fault landing with a body below it comes down beside it",
        "executor: with every node of its plan taken and a body below it, a fault landing hovers",
        (Edit("services/executor/faults.py",
              "    return next((xy for xy in spots if clear_spot(pos, xy, model, bodies)), None)\n",
              "    return None\n"),),
        "tests/test_fault_landing.py::"
        "test_a_lost_links_landing_with_nowhere_clear_is_reported_hovering_then_straight_down_or_beside[False]"),
    Handling(
        "a held vehicle taken over stays held",
        "executor: a take-over takes up the vehicle's old plan, held or not",
        (Edit("services/executor/vehicle_controller.py",
              "        if rel is not None and (state.held or mode == Mode.HOVERING):",
              "        if False and rel is not None and (state.held or mode == Mode.HOVERING):"),),
        "tests/test_takeover.py::test_a_held_vehicle_taken_over_stays_held_where_it_is[3.0-holding]"),
    Handling(
        "a request its requester gave up on is not planned",
        "planner: every request planned for its whole time limit, however long it queued",
        (Edit("services/planner/service.py", "            if req.reply_within > 0.0:",
              "            if False and req.reply_within > 0.0:"),),
        "tests/test_planner_service.py::test_a_request_whose_requester_stopped_waiting_is_not_planned"),
    Handling(
        "a request planned within what is left of its wait",
        "planner: every request planned for its whole time limit, however long it queued",
        (Edit("services/planner/service.py", "            if req.reply_within > 0.0:",
              "            if False and req.reply_within > 0.0:"),),
        "tests/test_planner_service.py::test_a_request_is_planned_within_what_is_left_of_its_wait"),
    Handling(
        "a rejoining vehicle in contact named",
        "planner: a replan that failed validation names no vehicle",
        (Edit("services/planner/registry.py", "                     failed_vehicle=rejoining), later",
              "                     failed_vehicle=\"\"), later"),),
        "tests/test_rejoin.py::test_two_held_vehicles_within_reach_of_each_other_rejoin_one_named_refused"),
    Handling(
        "every vehicle that cannot rejoin yet named at once",
        "planner: the first vehicle that cannot rejoin yet named, the others found one request later",
        (Edit("services/planner/replanning.py",
              "                blocked[vid] = f\"its way to {b.node!r} crosses where {sweep.vid} may be\"\n                break",
              "                blocked[vid] = f\"its way to {b.node!r} crosses where {sweep.vid} may be\"\n"
              "                return blocked"),),
        "tests/test_rejoin.py::test_every_vehicle_that_cannot_rejoin_yet_is_named_at_once"),
    Handling(
        "a packet read late takes effect at its delivery time",
        "simulator: a packet waits outside the queue until its own delivery runs (an advance past it misses it)",
        (Edit("services/sim/crazyflie/endpoint.py",
              "            heapq.heappush(self._pending, (due, next(self._order), data, addr))\n"
              "            asyncio.get_running_loop().call_later(max(due - self.clock(), 0.0), self.advance, due)\n",
              "            asyncio.get_running_loop().call_later(max(due - self.clock(), 0.0), lambda: (heapq.heappush("
              "self._pending, (due, next(self._order), data, addr)), self.advance(due)))\n"),),
        "tests/test_simcf.py::test_a_packet_read_late_takes_effect_at_its_delivery_time"),
    Handling(
        "the plan's clock waits for the late",
        "plan clock: every vehicle lets it run at full pace, however far behind its reference",
        (Edit("common/flight/plan_clock.py", "    if margin <= 0.0 or not params.enabled:\n", "    if True:\n"),),
        "tests/test_plan_clock.py::test_the_fleet_waits_for_a_vehicle_stopped_on_a_stale_pose_and_every_vehicle_arrives"),
    Handling(
        "an executor whose commands come late slows the plan's clock",
        "executor: its latency never slows its missions' clocks",
        (Edit("services/executor/service.py", "        if loop < 1.0 and running:\n", "        if False:\n"),),
        "tests/test_executor_frames.py::test_an_executor_whose_commands_come_late_runs_its_missions_clock_slower"),
)


class TargetMissing(Exception):
    """A disabling change's target text is not in its file exactly once."""


def apply(edit: Edit, root: Path) -> None:
    """Apply `edit` to the tree at `root`; `TargetMissing` unless its text occurs exactly once."""
    path = root / edit.path
    if not path.is_file():
        raise TargetMissing(f"{edit.path}: no such file")
    text = path.read_text()
    n = text.count(edit.old)
    if n != 1:
        raise TargetMissing(f"{edit.path}: the target text occurs {n} times (must be once): {edit.old!r}")
    path.write_text(text.replace(edit.old, edit.new))


def check_targets(root: Path, handlings: tuple[Handling, ...] = HANDLINGS) -> list[str]:
    """What is wrong with the targets in the tree at `root` ([] if every one is there, once), and
    whether each test's file defines its test function."""
    problems = []
    for h in handlings:
        for e in h.edits:
            path = root / e.path
            n = path.read_text().count(e.old) if path.is_file() else -1
            if n != 1:
                problems.append(f"{h.name}: {e.path}: " + ("no such file" if n < 0 else f"target text found {n} times")
                                + f": {e.old!r}")
        file, _, func = h.test.partition("::")
        test_file = root / file
        if not test_file.is_file() or f"def {func.partition('[')[0]}(" not in test_file.read_text():  # [a parameter set]
            problems.append(f"{h.name}: test {h.test} not found")
    return problems


def _ignore(_dir: str, names: list[str]) -> set[str]:
    return {n for n in names if n in SKIP or n.endswith(".pyc")}


def copy_tree(dest: Path, ref: str | None) -> Path:
    """The repository's working tree (or `ref`, exported) at `dest`."""
    if ref is None:
        shutil.copytree(REPO, dest, ignore=_ignore)
    else:
        dest.mkdir(parents=True)
        archive = subprocess.run(["git", "-C", str(REPO), "archive", "--format=tar", ref], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def first_error(log: Path, width: int = 110) -> str:
    """The first assertion or error line (`E ...`) of pytest's output in `log`, shortened."""
    for line in log.read_text(errors="replace").splitlines():
        if line.startswith("E "):
            text = " ".join(line[1:].split()).replace("|", "/")
            return text if len(text) <= width else text[:width - 3] + "..."
    return ""


def run_test(root: Path, node: str, log: Path) -> tuple[str, float]:
    """Run `node` in the tree at `root` with this repository's venv: ("pass" | "fail" | "error
    (rc N)" | "timeout", seconds); pytest's output goes to `log`."""
    python = REPO / ".venv" / "bin" / "python"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), *filter(None, [os.environ.get("PYTHONPATH")])])}
    started = time.monotonic()
    with log.open("w") as out:
        try:
            rc = subprocess.run([str(python), "-m", "pytest", "-q", "-p", "no:cacheprovider", "-o", "addopts=", node],
                                cwd=root, env=env, stdout=out, stderr=subprocess.STDOUT,
                                timeout=TEST_TIMEOUT_S).returncode
        except subprocess.TimeoutExpired:
            return "timeout", time.monotonic() - started
    took = time.monotonic() - started
    return {0: "pass", 1: "fail"}.get(rc, f"error (rc {rc})"), took


def _short(node: str) -> str:
    file, _, func = node.partition("::")
    return f"`{Path(file).name}::{func}`"


def table(rows: list[tuple[Handling, str, str, str]]) -> str:
    """Markdown: one row per (handling, result with it, result without it, how it failed without)."""
    lines = ["| handling disabled | disabling change | test | with the handling | disabled | as expected | "
             "first failure, disabled |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for h, base, off, why in rows:
        ok = base == "pass" and off == h.disabled
        lines.append(f"| {h.name} | {h.change} | {_short(h.test)} | {base} | {off}"
                     f"{' (expected: pass)' if h.disabled == 'pass' else ''} | {'yes' if ok else '**no**'} | "
                     f"{why} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.check_handlers", description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", default=[], metavar="TEXT",
                    help="only the handlings whose name or test contains one of these")
    ap.add_argument("--ref", help="check this git revision (git archive) instead of the working tree")
    ap.add_argument("--list", action="store_true", help="list the handlings and their targets, run nothing")
    ap.add_argument("--keep", action="store_true", help="keep the copies and logs (their directory is printed)")
    args = ap.parse_args(argv)

    chosen = tuple(h for h in HANDLINGS if not args.only or any(t in h.name or t in h.test for t in args.only))
    if not chosen:
        print(f"no handling matches {args.only}", file=sys.stderr)
        return 2
    if args.list:
        for h in chosen:
            print(f"{h.name}: {h.change}; {', '.join(e.path for e in h.edits)}; {h.test}")
        return 0
    ref, source = None, "the working tree"
    if args.ref:  # resolved once: every copy is of the same commit, wherever HEAD moves meanwhile
        ref = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--verify", f"{args.ref}^{{commit}}"],
                             capture_output=True, text=True, check=True).stdout.strip()
        source = f"git {args.ref} ({ref[:7]})"
    work = Path(tempfile.mkdtemp(prefix="check-handlers-"))
    try:
        pristine = copy_tree(work / "pristine", ref)
        problems = check_targets(pristine, chosen)
        if problems:
            print("disabling changes whose target is gone (update HANDLINGS in tests/check_handlers.py):",
                  *problems, sep="\n  ", file=sys.stderr)
            return 2
        print(f"checking {len(chosen)} handlings in {source}", flush=True)
        started = time.monotonic()
        baseline: dict[str, str] = {}
        for node in dict.fromkeys(h.test for h in chosen):
            log = work / f"base-{len(baseline)}.log"
            result, took = run_test(pristine, node, log)
            baseline[node] = result
            print(f"with every handling: {_short(node)}: {result} ({took:.0f} s) {first_error(log)}", flush=True)
        rows = []
        for i, h in enumerate(chosen):
            copy = copy_tree(work / f"off-{i}", ref)
            for edit in h.edits:
                apply(edit, copy)
            log = work / f"off-{i}.log"
            result, took = run_test(copy, h.test, log)
            why = first_error(log)
            print(f"without {h.name}: {_short(h.test)}: {result} ({took:.0f} s) {why}", flush=True)
            rows.append((h, baseline[h.test], result, why))
            if not args.keep:
                shutil.rmtree(copy)
        print(f"\n{len(rows)} handlings, {source}, {(time.monotonic() - started) / 60:.1f} min\n")
        print(table(rows))
        return 0 if all(base == "pass" and off == h.disabled for h, base, off, _why in rows) else 1
    finally:
        if args.keep:
            print(f"\ncopies and logs in {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
