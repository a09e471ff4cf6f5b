"""The executor's control cycle: how it takes the motion capture's frames (`ExecutorService._fuse`:
a cycle that found several frames waiting, it ran late, fuses each owned vehicle's newest pose
once, and remembers every body where its newest frame saw it), how it spreads the vehicles'
states over its cycles (`ExecutorService._cycle`), and how its latency slows its missions' plan
clocks (`ExecutorService._run_clocks`)."""

from __future__ import annotations

import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from common.bus.keys import Keys
from common.bus.messages import FramePose, PoseFrame
from common.bus.session import ZenohConfig
from common.domain.vehicle_model import VehicleModel
from common.flight.plan_clock import ClockParams
from services.executor.service import REACT_WINDOW, ExecutorService
from services.executor.vehicle_controller import VehicleController
from tests.support.closed_loop import plan_for, reference_steps
from tests.support.sent import SentMessages

pytestmark = pytest.mark.compute

REPO = Path(__file__).resolve().parents[1]


def service() -> ExecutorService:
    return ExecutorService("e1", ZenohConfig.client("tcp/127.0.0.1:1"), Keys("frames"))  # never run: no session


def test_a_late_cycle_fuses_each_vehicles_newest_pose_once() -> None:
    svc = service()
    for vid in ("cf1", "cf2"):
        svc.controllers[vid] = VehicleController(vid, VehicleModel(), owner="e1", bank=svc.bank)
    first = [PoseFrame(t=10.0 + 0.01 * k, seq=k, poses=[FramePose("cf1", 0.001 * k, 0.0, 0.0, 0.0),
                                                         FramePose("cf2", 1.0, 0.001 * k, 0.0, 0.0)])
             for k in range(3)]
    svc._fuse(first[:1])  # the first pose starts each filter
    # a late cycle: two frames waited, cf2 only in the older one
    late = [first[1], PoseFrame(t=10.02, seq=2, poses=[FramePose("cf1", 0.002, 0.0, 0.0, 0.0)])]
    svc._fuse(late)
    cf1, cf2 = (svc.controllers[v].estimator for v in ("cf1", "cf2"))
    assert (cf1.accepted, cf1.rejected, cf1.t) == (2, 0, 10.02)  # the newer frame's pose only
    assert (cf2.accepted, cf2.t) == (2, 10.01)  # its newest pose, from the older frame
    assert svc.last_seen["cf1"][0].seq == 2 and svc.last_seen["cf2"][0].seq == 1
    svc.bodies.settle(10.02)
    assert svc.bodies.pos[svc.bodies.rows["cf1"]].tolist() == [0.002, 0.0, 0.0]
    assert svc.bodies.pos[svc.bodies.rows["cf2"]].tolist() == [1.0, 0.001, 0.0]


class Sent:
    """Stands in for the bus's publishers (`KeyedPublishers.put`): what each cycle put, by key."""

    def __init__(self) -> None:
        self.puts: list[str] = []

    def put(self, key: str, _msg: object) -> None:
        self.puts.append(key)


def test_each_vehicles_state_goes_out_once_in_five_cycles_and_every_cycle_sends_a_fifth() -> None:
    svc = service()
    vids = [f"cf{i:02d}" for i in range(12)]
    for vid in vids:
        svc.controllers[vid] = VehicleController(vid, VehicleModel(), owner="e1", bank=svc.bank)
    svc._cmd, svc._batch, svc._event = Sent(), Sent(), Sent()
    per_cycle, per_vehicle = [], Counter()
    for n in range(20):
        svc._state, svc._states = states, batches = Sent(), SentMessages()
        svc._cycle(100.0 + 0.01 * n, n, 0.0, 0.0)
        per_cycle.append(len(states.puts))
        per_vehicle.update(states.puts)
        [batch] = batches.msgs  # the cycle's states together, as the fleet's services read them
        assert batch.owner == "e1" and [st.vid for st in batch.states] == states.puts
    assert svc.state_every == 5
    assert all(c in (2, 3) for c in per_cycle), per_cycle  # 12 vehicles over 5 cycles: never all at once
    assert per_vehicle == {vid: 4 for vid in vids}  # 20 cycles: each vehicle's state 4 times (20 Hz)


@pytest.mark.parametrize("latency", [0.05, 0.25])
def test_an_executor_whose_commands_come_late_runs_its_missions_clock_slower(latency: float) -> None:
    """Commands 0.25 s after the poses they use (p99 of the recent cycles): the executor runs the
    clock of its running mission at 0.15 / 0.25 of its pace, says so to the others (`PlanDelay`)
    and gives its vehicles that pace; at 0.05 s the plan runs at full pace and nothing is sent."""
    svc = service()
    model = VehicleModel(margin=0.03)
    plan = plan_for("cf1", reference_steps(model), model, t0=100.0)
    ctl = svc.controllers["cf1"] = VehicleController("cf1", model, owner="e1", bank=svc.bank)
    assert ctl.load(plan)
    ctl.start(100.0)
    svc.plans["cf1"] = plan
    svc._delay = sent = SentMessages()
    for _ in range(REACT_WINDOW):
        svc.stats.add_latency(latency, latency)
    for n in range(101):  # one second of cycles
        svc._run_clocks(100.0 + 0.01 * n)
    if latency < ClockParams().latency_s:
        assert not sent.msgs and svc.stats.slowed == 0 and ctl.pace == 1.0 and ctl.delay == 0.0
        return
    assert svc.stats.loop_pace == pytest.approx(0.6) and svc.stats.slowed == 101
    assert sent.msgs and all(m.pace == pytest.approx(0.6) and m.source == "e1" for m in sent.msgs)
    assert ctl.pace == pytest.approx(0.6) and ctl.delay == pytest.approx(0.4, abs=0.01)  # 1 s at 0.6


@pytest.mark.parametrize("fly", [False, True], ids=["driving", "hovering"])
def test_the_executor_cycle_benchmark_ticks_every_vehicle_on_its_plan(tmp_path: Path, fly: bool) -> None:
    """`bench.executor_cycle` (bench/ sits above tests/ in the import contracts: run as a user does):
    the cycle's cost per vehicle, and every vehicle still on its plan at the end (a cycle that
    stopped ticking them, or held them, would cost less and say nothing)."""
    run = subprocess.run([sys.executable, "-m", "bench.executor_cycle", "--vehicles", "2,6", "--rounds", "3",
                          "--cycles", "150", "--out", str(tmp_path), *(["--fly"] if fly else [])],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = [line.split() for line in run.stdout.splitlines() if line.split()[:1] in (["2"], ["6"])]
    assert [row[:2] for row in rows] == [["2", "flying" if fly else "driving"], ["6", "flying" if fly else "driving"]], \
        run.stdout
    assert all(0.0 < float(row[2]) <= float(row[3]) for row in rows), run.stdout
    assert (tmp_path / "executor_cycle.png").stat().st_size > 10_000
