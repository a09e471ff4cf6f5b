"""Bad input, fuzzed (hypothesis): every wire message decoder and every file loader, fed random bytes,
random YAML/JSON/msgpack structures and mutations of valid documents, raises nothing but its
documented error (`BadPayload` for messages, `InputError` for maps, scenarios, radios, mocap and
compose files, `PlanFileError` for plan files); and a running executor flooded with garbage on every
key it listens to drops and counts it and keeps working."""

from __future__ import annotations

import asyncio
import contextlib
import copy
import inspect
import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import msgspec
import pytest
import yaml
import zenoh
from hypothesis import HealthCheck, given, reject, settings
from hypothesis import strategies as st

from common.bus import messages
from common.bus.keys import Keys
from common.bus.messages import MAX_MESSAGE_BYTES, Codec, PlanStep, VehiclePlan, VehicleState
from common.bus.pubsub import BadPayload, decode_payload, drop_name, subscribe
from common.bus.session import ZenohConfig, open_session
from common.deploy.compose import load_compose
from common.deploy.radios import load_radios
from common.domain.mapfile import MAPS_DIR, load_map
from common.domain.planfile import PlanFileError, PlanModel, Task, decode_plan, encode_plan
from common.errors import InputError
from services.executor.service import ExecutorService
from services.mocap_bridge.config import load_mocap
from services.planner.graph.fleet_graph import build_graph
from services.planner.maps.loading import load_graph, problem_from_request
from services.planner.maps.tasks import load_scenario
from services.planner.registry import run_planner

REPO = Path(__file__).resolve().parents[1]
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

MESSAGE_TYPES = [t for t in vars(messages).values()
                 if inspect.isclass(t) and issubclass(t, msgspec.Struct) and t.__module__ == messages.__name__]
st.register_type_strategy(PlanModel, st.just(PlanModel()))  # its numbers are checked (positive)

# ---- strategies ------------------------------------------------------------------------------------

INT64 = st.integers(-(2 ** 63), 2 ** 64 - 1)
SCALARS = (st.none() | st.booleans() | INT64 | st.floats() | st.text(max_size=12)
           | st.sampled_from(["", "*", "a/b", "$*", "..", "${X}", "-1", "1e999", "radio://0/80", "udp://h:1"]))
TREES = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=4)
                     | st.dictionaries(st.text(max_size=8), inner, max_size=4), max_leaves=10)


def _paths(doc: Any, prefix: tuple = ()) -> Iterator[tuple]:
    yield prefix
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        yield from _paths(value, (*prefix, key))


@st.composite
def mutations(draw: st.DrawFn, doc: Any) -> Any:
    """`doc` (YAML/JSON builtins) with one to three values replaced, removed or added."""
    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(list(_paths(doc))))
        if not path:
            return draw(TREES)
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        op = draw(st.sampled_from(["replace", "replace", "remove", "add"]))
        if op == "replace":
            parent[path[-1]] = draw(TREES)
        elif op == "remove":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.text(max_size=8))] = draw(TREES)
        else:
            parent.append(draw(TREES))
    return doc


def documents(valid: Any) -> st.SearchStrategy[Any]:
    """Random structures, and mutations of a valid document (most examples)."""
    return st.one_of(TREES, mutations(valid), mutations(valid), mutations(valid))


def yaml_texts(valid: Any) -> st.SearchStrategy[bytes]:
    texts = documents(valid).map(lambda d: yaml.safe_dump(d, allow_unicode=True).encode())
    return st.one_of(st.binary(max_size=200), texts, texts, texts)


# ---- wire messages ---------------------------------------------------------------------------------

def _decoded(typ: type, data: bytes) -> None:
    try:
        msg = decode_payload(Codec(typ), zenoh.ZBytes(data))
    except BadPayload as bad:
        assert bad.reason == "malformed"
    else:
        assert isinstance(msg, typ)


@pytest.mark.compute
@pytest.mark.parametrize("typ", MESSAGE_TYPES, ids=lambda t: t.__name__)
@settings(FUZZ, max_examples=40)
@given(data=st.data())
def test_message_decoders_raise_only_bad_payload(typ: type, data: st.DataObject) -> None:
    # hypothesis passes a mutable field's default as msgspec's Factory: call it
    valid = msgspec.to_builtins(data.draw(st.from_type(typ)), enc_hook=lambda factory: factory.factory())
    try:
        msgspec.msgpack.encode(valid)
    except OverflowError:  # an int beyond msgpack's 64 bits: not a message anyone can send
        reject()
    payload = data.draw(st.one_of(
        st.binary(max_size=64),
        documents(valid).map(msgspec.msgpack.encode),
        st.just(msgspec.msgpack.encode(valid)),
    ))
    _decoded(typ, payload)


def test_oversized_payloads_are_rejected_before_decoding() -> None:
    big = msgspec.msgpack.encode({"vid": "x" * MAX_MESSAGE_BYTES})
    with pytest.raises(BadPayload) as bad:
        decode_payload(Codec(messages.Pose), zenoh.ZBytes(big))
    assert bad.value.reason == "oversized"
    with pytest.raises(msgspec.ValidationError, match="exceeds"):
        Codec(messages.Pose).decode(big)


# ---- files -----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def _load_yaml(path: Path) -> Any:
    return yaml.safe_load(path.read_text())


def _only_input_errors(load: Callable[[Path], object], path: Path, data: bytes) -> None:
    path.write_bytes(data)
    with contextlib.suppress(InputError):
        load(path)


TOWN = load_graph("town")
MOCAP = {"backend": "vicon", "options": {"hostname": "10.0.0.5"}, "rate_hz": 100, "bodies": {"cf_01": "cf1"},
         "lost_after_s": 0.1, "latency_s": 0.0, "sim": {"pos_std": 0.001, "dropout_rate_hz": 0.5, "seed": 3}}
LOADERS: dict[str, tuple[Any, Callable[[Path], object]]] = {
    "map": (_load_yaml(MAPS_DIR / "town.yaml"), lambda p: build_graph(load_map(p), source=str(p))),
    "scenario": (_load_yaml(MAPS_DIR / "scenarios" / "town_8.yaml"), lambda p: load_scenario(p, TOWN)),
    "radios": (_load_yaml(REPO / "deploy" / "radios-town.yaml"), load_radios),
    "mocap": (MOCAP, load_mocap),
    "compose": (_load_yaml(REPO / "compose.yaml"), load_compose),
}


@pytest.mark.compute
@pytest.mark.parametrize("name", LOADERS)
@FUZZ
@given(data=st.data())
def test_file_loaders_raise_only_input_errors(name: str, fuzz_dir: Path, data: st.DataObject) -> None:
    valid, load = LOADERS[name]
    _only_input_errors(load, fuzz_dir / f"{name}.yaml", data.draw(yaml_texts(valid)))


@pytest.fixture(scope="module")
def plan_doc() -> Any:
    tasks = {"cf1": Task(start="WP1", goal="EP4"), "cf2": Task(start="EP1", goal="WP6")}
    plan, _ = run_planner(problem_from_request("town", tasks, "sipp"), "sipp", 0.5, 10.0, 0)
    assert plan is not None
    return json.loads(encode_plan(plan))


@pytest.mark.compute
@FUZZ
@given(data=st.data())
def test_plan_decoder_raises_only_plan_file_errors(plan_doc: Any, data: st.DataObject) -> None:
    payload = data.draw(st.one_of(st.binary(max_size=200), documents(plan_doc).map(lambda d: json.dumps(d).encode())))
    try:
        decode_plan(payload, "fuzz.json")
    except PlanFileError as exc:
        assert str(exc).startswith("fuzz.json: ")


# ---- a running service under a flood of garbage ----------------------------------------------------

KEYS = Keys("fuzz")
FLOODED = {KEYS.vehicle("v1", "plan"): VehiclePlan, KEYS.mocap_frame: messages.PoseFrame,
           KEYS.vehicle("v1", "telemetry"): messages.Telemetry, KEYS.executor_states("e2"): messages.VehicleStates,
           KEYS.mission("m1", "start"): messages.MissionStart, KEYS.mission("m1", "abort"): messages.MissionAbort}
"""Every key the executor listens to, and the type it expects there."""


def _plan() -> VehiclePlan:
    steps = [PlanStep(node="A", t=0.0, pos=(0.0, 0.0, 0.0), kind="parking"),
             PlanStep(node="B", t=10.0, pos=(0.5, 0.0, 0.0), kind="waypoint", edge="drive")]
    return VehiclePlan(vid="v1", mission="m1", map="town", steps=steps, model=PlanModel())


@pytest.mark.timeout(60)
def test_executor_flooded_with_garbage_drops_counts_and_keeps_working(zenoh_router: str) -> None:
    garbage = [b"", b"\xc1", b"\x92\x01\x02", msgspec.msgpack.encode({"vid": 3}), b"\xff" * 300,
               msgspec.msgpack.encode({"vid": "v1", "t": 1.0, "unknown": True})]
    oversized = b"\x00" * (MAX_MESSAGE_BYTES + 1)

    async def scenario() -> ExecutorService:
        svc = ExecutorService("e1", ZenohConfig.client(zenoh_router), KEYS)
        run = asyncio.create_task(svc.run())
        attacker = open_session(ZenohConfig.client(zenoh_router))
        states: list[VehicleState] = []
        try:
            subscribe(attacker, KEYS.vehicle("v1", "state"), VehicleState, lambda s, _k: states.append(s))
            await asyncio.sleep(0.5)
            block = zenoh.CongestionControl.BLOCK  # every message reaches the executor
            for _ in range(50):
                for key in FLOODED:
                    for payload in garbage:
                        attacker.put(key, payload, congestion_control=block)
            attacker.put(KEYS.mocap_frame, oversized, congestion_control=block)
            await asyncio.sleep(0.5)
            assert not run.done(), "the executor stopped under the flood"
            attacker.put(KEYS.vehicle("v1", "plan"), msgspec.msgpack.encode(_plan()))
            deadline = time.monotonic() + 5.0
            while not any(s.mission == "m1" for s in states) and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            assert any(s.mission == "m1" and s.owner == "e1" for s in states), "no state for the plan after the flood"
        finally:
            svc.stop()
            assert await run == 0
            attacker.close()
        return svc

    counters = asyncio.run(scenario()).counters
    for key, typ in FLOODED.items():
        assert counters[drop_name("malformed", typ, key)] == 50 * len(garbage)
    assert counters[drop_name("oversized", messages.PoseFrame, KEYS.mocap_frame)] == 1
    assert not any(name.startswith("drop:handler") for name in counters)
