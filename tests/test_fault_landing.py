"""Where a fault landing comes down in a fleet: the executor tells its controllers where the other
vehicles are and where other executors' fault landings come down (their `VehicleState.landing`,
over the bus), and `safe_landing_steps` passes over those nodes (docs/control.md, faults)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest
import zenoh

from common.bus.keys import Keys
from common.bus.messages import VehicleState
from common.bus.pubsub import Publisher
from common.bus.session import ZenohConfig
from common.domain.vehicle_model import VehicleModel
from services.executor.faults import safe_landing_steps
from services.executor.service import ExecutorService
from tests.support.closed_loop import reference_steps

KEYS = Keys("landing")
MODEL = VehicleModel()
STEPS = reference_steps(MODEL)
PADS = {s.node: s.pos for s in STEPS if s.node in ("l1", "l2")}


def state(vid: str, owner: str, landing: tuple[float, float, float] | None) -> VehicleState:
    return VehicleState(vid=vid, t=0.0, owner=owner, mode="landing", x=2.0, y=0.45, z=0.5, yaw=0.0,
                        landing=landing)


@pytest.mark.timeout(30)
def test_another_executors_fault_landing_is_heard_and_its_node_passed_over(
        zenoh_router: str, zsession: Callable[..., zenoh.Session]) -> None:
    above_l2 = (PADS["l2"][0], PADS["l2"][1], 0.5)

    def target(svc: ExecutorService) -> str:
        return safe_landing_steps(above_l2, 0.0, STEPS, MODEL, svc._bodies_besides("cf1"))[-1].node

    async def scenario() -> list[str]:
        svc = ExecutorService("e1", ZenohConfig.client(zenoh_router), KEYS)
        run = asyncio.create_task(svc.run())
        pub = Publisher(zsession(), KEYS.vehicle("cf2", "state"), VehicleState)
        chosen = []
        try:
            for landing in (None, PADS["l2"], None):
                pub.put(state("cf2", "e2", landing))
                for _ in range(100):  # until the executor has heard it
                    await asyncio.sleep(0.02)
                    if ("cf2" in svc._landings) == (landing is not None):
                        break
                chosen.append(target(svc))
            pub.put(state("cf1", "e1", PADS["l2"]))  # its own vehicle's state: not another's landing
            await asyncio.sleep(0.3)
            chosen.append(target(svc))
        finally:
            svc.stop()
            assert await run == 0
        return chosen

    # nothing there: the nearest (l2); cf2 of e2 coming down on l2: l1; cf2 landed elsewhere: l2
    assert asyncio.run(scenario()) == ["l2", "l1", "l2", "l2"]
