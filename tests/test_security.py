"""Authentication and access control of the shipped router configuration, over real zenoh sessions:
sessions without valid credentials are refused; each role may only do what common/deploy/acl.py grants
(only executors command vehicles, only the planner serves planner/plan and the operator's querier
sees its queryable, only gateways publish telemetry, only executors hold executor tokens); TLS with a
CA made at test time."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from common.bus.args import credentials
from common.bus.keys import Keys
from common.bus.liveliness import declare_alive, watch_alive
from common.bus.messages import Cmd, PlanReply, PlanRequest, SimTruth, SimTruthFrame, StopSetpoint, Telemetry
from common.bus.pubsub import Publisher, QueryError, find_queryable, query, serve, subscribe
from common.bus.session import InProcessRouter, ZenohConfig, free_tcp_endpoint, open_session
from common.deploy.acl import ROUTER_CONFIG, render
from common.deploy.credentials import Credentials, make_credentials
from common.errors import InputError

KEYS = Keys("sec")
REFUSE_MS = 500
"""How long a refused client keeps trying before open() fails."""

Sessions = Callable[..., zenoh.Session]


@pytest.fixture
def creds(tmp_path: Path) -> Credentials:
    return make_credentials(tmp_path / "secrets")


@pytest.fixture
def router(creds: Credentials) -> Iterator[InProcessRouter]:
    with InProcessRouter(**creds.router_options()) as r:
        yield r


@pytest.fixture
def role(router: InProcessRouter, creds: Credentials) -> Iterator[Sessions]:
    """Factory: a client session authenticated as a role."""
    sessions: list[zenoh.Session] = []

    def open_as(name: str) -> zenoh.Session:
        sessions.append(open_session(router.client_config(**creds.options(name))))
        return sessions[-1]

    yield open_as
    for s in reversed(sessions):
        s.close()


def cmd(owner: str) -> Cmd:
    return Cmd(vid="x", owner=owner, seq=1, t=time.time(), setpoint=StopSetpoint())


def telemetry(gateway: str) -> Telemetry:
    return Telemetry(vid="x", t=time.time(), gateway=gateway, vbat=3.9, link_quality=1.0, sent=0,
                     dropped=0, cmd_rate_hz=0.0)


async def eventually(predicate: Callable[[], bool], timeout: float = 3.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.01)


def test_shipped_router_config_is_the_role_table() -> None:
    assert ROUTER_CONFIG.read_text() == render(), "regenerate: python -m common.deploy.acl > deploy/router.json5"


@pytest.mark.parametrize("options", [
    {},
    {"user": "executor", "password": "not-the-password"},
    {"user": "intruder", "password": "whatever"},
], ids=["no-credentials", "wrong-password", "unknown-user"])
def test_sessions_without_valid_credentials_are_refused(router: InProcessRouter, creds: Credentials,
                                                        options: dict[str, str]) -> None:
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        open_session(router.client_config(connect_timeout_ms=REFUSE_MS, **options))
    open_session(router.client_config(connect_timeout_ms=REFUSE_MS, **creds.options("executor"))).close()


def _publish_check(role: Sessions, key: str, make: Callable[[str], object], typ: type, reader: str,
                   denied: str, allowed: str, sender: Callable[[Any], str] | None = None) -> list[str]:
    """`denied` then `allowed` publish on `key` to a `reader` subscriber: the senders that arrived
    (as `sender` reads them from a message; a command's owner, telemetry's gateway by default)."""
    sender = sender or (lambda msg: msg.owner if typ is Cmd else msg.gateway)
    rx = role(reader)
    tx_denied, tx_allowed = role(denied), role(allowed)

    async def scenario() -> list[str]:
        got: list[str] = []
        subscribe(rx, key, typ, lambda msg, _k: got.append(sender(msg)))
        bad, good = Publisher(tx_denied, key, typ), Publisher(tx_allowed, key, typ)
        await eventually(lambda: good.matched)
        for _ in range(5):
            bad.put(make(denied))
            good.put(make(allowed))
            await asyncio.sleep(0.02)
        await eventually(lambda: len(got) >= 5)
        await asyncio.sleep(0.2)
        return got

    return asyncio.run(scenario())


@pytest.mark.timeout(20)
def test_only_executors_command_vehicles(role: Sessions) -> None:
    got = _publish_check(role, KEYS.vehicle("x", "cmd"), cmd, Cmd, reader="gateway", denied="mission",
                         allowed="executor")
    assert got == ["executor"] * 5


@pytest.mark.timeout(20)
def test_only_gateways_publish_telemetry(role: Sessions) -> None:
    got = _publish_check(role, KEYS.vehicle("x", "telemetry"), telemetry, Telemetry, reader="executor",
                         denied="executor", allowed="gateway")
    assert got == ["gateway"] * 5


@pytest.mark.timeout(20)
def test_only_the_simulator_publishes_ground_truth_frames(role: Sessions) -> None:
    """The frames a mission judges separation on (`sim/truths`) reach it from the simulator only."""
    def frame(name: str) -> SimTruthFrame:
        return SimTruthFrame(t=time.time(), truths=[SimTruth(vid=name, t=time.time(), x=0.0, y=0.0, z=0.0, yaw=0.0)])

    got = _publish_check(role, KEYS.sim_truths, frame, SimTruthFrame, reader="mission", denied="executor",
                         allowed="sim", sender=lambda msg: msg.truths[0].vid)
    assert got == ["sim"] * 5


@pytest.mark.timeout(20)
def test_only_the_planner_serves_plans(role: Sessions) -> None:
    impostor, client = role("executor"), role("mission")
    request = PlanRequest(map="town", tasks={})

    async def answer(_req: PlanRequest) -> PlanReply:
        return PlanReply(ok=False, error="forged")

    async def scenario() -> None:
        serve(impostor, KEYS.planner_plan, PlanRequest, PlanReply, answer)
        assert not await find_queryable(client, KEYS.planner_plan, 0.3)  # its declaration never passes
        with pytest.raises(QueryError, match="no queryable answered"):
            await query(client, KEYS.planner_plan, request, PlanReply, timeout=2.0)
        serve(role("planner"), KEYS.planner_plan, PlanRequest, PlanReply, answer)
        # the planner's does, to the operator's querier: a client waiting for it (`query(find_s=)`)
        # asks as soon as it is there instead of waiting out `find_s`
        assert await find_queryable(client, KEYS.planner_plan, 1.0)
        assert (await query(client, KEYS.planner_plan, request, PlanReply, timeout=2.0)).error == "forged"
        with pytest.raises(QueryError, match="no queryable answered"):  # only the operator asks for plans
            await query(role("gateway"), KEYS.planner_plan, request, PlanReply, timeout=2.0)

    asyncio.run(scenario())


@pytest.mark.timeout(20)
def test_only_executors_hold_executor_tokens(role: Sessions) -> None:
    """A forged executor token would take vehicles in the executors' assignment."""
    watcher = role("gateway")
    _forged = declare_alive(role("mission"), KEYS, "executor", "forged")
    _real = declare_alive(role("executor"), KEYS, "executor", "e1")

    async def scenario() -> frozenset[str]:
        alive = await watch_alive(watcher, KEYS, "executor")
        await asyncio.sleep(0.3)
        return alive.instances

    assert asyncio.run(scenario()) == {"e1"}


def test_credentials_from_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "pw").write_text("s3cret\n")
    monkeypatch.setenv("FLEET_ZENOH_USER", "planner")
    monkeypatch.setenv("FLEET_ZENOH_PASSWORD_FILE", str(tmp_path / "pw"))
    assert credentials() == ("planner", "s3cret")
    monkeypatch.delenv("FLEET_ZENOH_USER")
    with pytest.raises(InputError, match="go together"):
        credentials()
    monkeypatch.setenv("FLEET_ZENOH_USER", "planner")
    monkeypatch.setenv("FLEET_ZENOH_PASSWORD_FILE", str(tmp_path / "missing"))
    with pytest.raises(InputError, match="cannot read"):
        credentials()


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=30)


@pytest.fixture
def tls_files(tmp_path: Path) -> dict[str, str]:
    """A CA and a server certificate for 127.0.0.1 signed by it, made with the openssl CLI."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is not installed: cannot make test certificates")
    ec = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")
    _openssl("req", "-x509", *ec, "-keyout", "ca.key", "-out", "ca.pem", "-days", "1", "-subj", "/CN=fleet test CA",
             cwd=tmp_path)
    _openssl("req", *ec, "-keyout", "server.key", "-out", "server.csr", "-subj", "/CN=localhost", cwd=tmp_path)
    (tmp_path / "ext.cnf").write_text("subjectAltName=IP:127.0.0.1\nbasicConstraints=CA:FALSE\n")
    _openssl("x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
             "-out", "server.pem", "-days", "1", "-extfile", "ext.cnf", cwd=tmp_path)
    return {name: str(tmp_path / name) for name in ("ca.pem", "server.pem", "server.key")}


@pytest.mark.timeout(20)
def test_tls_router_with_access_control(creds: Credentials, tls_files: dict[str, str]) -> None:
    endpoint = free_tcp_endpoint().replace("tcp/", "tls/", 1)
    tls = {"listen_certificate": tls_files["server.pem"], "listen_private_key": tls_files["server.key"]}
    trusted = {"root_ca_certificate": tls_files["ca.pem"]}
    with InProcessRouter(endpoint, tls=tls, **creds.router_options()):
        def client(name: str, **options) -> ZenohConfig:
            return ZenohConfig.client(endpoint, connect_timeout_ms=REFUSE_MS, **creds.options(name), **options)

        with pytest.raises(zenoh.ZError):  # the server's certificate is not trusted without the CA
            open_session(client("gateway"))
        gateway, executor = open_session(client("gateway", tls=trusted)), open_session(client("executor", tls=trusted))
        try:
            async def scenario() -> list[str]:
                got: list[str] = []
                subscribe(gateway, KEYS.vehicle("x", "cmd"), Cmd, lambda msg, _k: got.append(msg.owner))
                pub = Publisher(executor, KEYS.vehicle("x", "cmd"), Cmd)
                await eventually(lambda: pub.matched)
                pub.put(cmd("executor"))
                await eventually(lambda: bool(got))
                return got

            assert asyncio.run(scenario()) == ["executor"]
        finally:
            gateway.close()
            executor.close()
