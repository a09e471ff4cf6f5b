"""Who may do what on the bus: one zenoh user per role, and the router's access control for them.

The table `ROLES` is the policy; `router_config()` renders it as the shipped router configuration
(`deploy/router.json5`, checked against this table by tests/test_security.py). Everything not granted
is denied (`default_permission: deny`), and a session without valid credentials is refused by the
router's user-password authentication before any of this applies.

Key expressions below are relative to ``fleet/<any fleet>/``. Each role also owns its liveliness
token ``alive/<role>/*`` and its health topic ``stats/<role>/*``. What a capability grants, seen
from the router (`ingress`: from the session; `egress`: to it):

| capability | ingress | egress |
| --- | --- | --- |
| publish | put | declare_subscriber (a publisher only sends what matches a subscriber) |
| subscribe | declare_subscriber | put |
| serve | declare_queryable, reply | query |
| query | query | reply, declare_queryable (a querier matches the queryables it can reach) |
| watch (liveliness) | declare_liveliness_subscriber, liveliness_query | liveliness_token, reply |
| token | liveliness_token | |
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common.bus.session import KEEP_ALIVE, LEASE_MS

ROUTER_CONFIG = Path(__file__).resolve().parents[2] / "deploy" / "router.json5"
"""The shipped router configuration (zenohd `-c`, `fleet router --config`, `InProcessRouter`)."""

USERS_FILE_IN_CONTAINER = "/run/secrets/zenoh-users"
"""Where the router configuration expects the user-password dictionary (a compose secret)."""

CAPABILITIES: dict[str, tuple[tuple[str, tuple[str, ...]], ...]] = {
    "publish": (("ingress", ("put",)), ("egress", ("declare_subscriber",))),
    "subscribe": (("ingress", ("declare_subscriber",)), ("egress", ("put",))),
    "serve": (("ingress", ("declare_queryable", "reply")), ("egress", ("query",))),
    "query": (("ingress", ("query",)), ("egress", ("reply", "declare_queryable"))),
    "watch": (("ingress", ("declare_liveliness_subscriber", "liveliness_query")),
              ("egress", ("liveliness_token", "reply"))),
    "token": (("ingress", ("liveliness_token",)),),
}


@dataclass(frozen=True)
class Role:
    """What one role's sessions may do, as key expressions under ``fleet/*/``."""

    publish: tuple[str, ...] = ()
    subscribe: tuple[str, ...] = ()
    serve: tuple[str, ...] = ()
    query: tuple[str, ...] = ()
    watch: tuple[str, ...] = ()

    def grants(self, name: str) -> dict[str, tuple[str, ...]]:
        """Capability -> key expressions (under ``fleet/*/``), with the role's own token and stats."""
        own = {"token": (f"alive/{name}/*",), "publish": (*self.publish, f"stats/{name}/*")}
        caps = {"subscribe": self.subscribe, "serve": self.serve, "query": self.query, "watch": self.watch, **own}
        return {cap: keys for cap, keys in caps.items() if keys}


ROLES: dict[str, Role] = {
    "executor": Role(
        publish=("vehicle/*/cmd", "gateway/*/cmd", "vehicle/*/state", "executor/*/states", "vehicle/*/event",
                 "vehicle/*/action", "mission/*/delay"),
        subscribe=("vehicle/*/plan", "vehicle/*/team_plan", "mocap/frame", "vehicle/*/pose", "vehicle/*/telemetry",
                   "executor/*/states", "vehicle/*/event", "vehicle/*/action_status", "mission/*/start",
                   "mission/*/abort", "mission/*/delay"),
        watch=("alive/executor/*",)),
    "planner": Role(publish=("vehicle/*/plan", "vehicle/*/team_plan"), serve=("planner/plan", "planner/graph")),
    "gateway": Role(publish=("vehicle/*/telemetry", "vehicle/*/event"),
                    subscribe=("vehicle/*/cmd", "gateway/*/cmd", "mocap/frame", "estop"),
                    watch=("alive/executor/*",)),
    "sim": Role(publish=("sim/truth/*", "sim/truths", "sim/mocap", "vehicle/*/event"), subscribe=("sim/fault/*",)),
    "mocap": Role(publish=("mocap/frame", "vehicle/*/pose", "vehicle/*/event"), subscribe=("sim/mocap",)),
    "telemetry": Role(subscribe=("vehicle/*/plan", "vehicle/*/state", "vehicle/*/telemetry", "sim/truth/*"),
                      query=("planner/graph",)),
    # the simulated ground-air team of paper 002 (`fleet sim team`): runs the executors' actions
    "team-sim": Role(publish=("vehicle/*/action_status", "sim/truth/*"), subscribe=("vehicle/*/action",)),
    # the operator: runs missions, watches everything, injects simulator faults; never commands a vehicle
    "mission": Role(publish=("vehicle/*/plan", "vehicle/*/team_plan", "mission/*/start", "mission/*/abort",
                             "sim/fault/*", "estop"),
                    subscribe=("**",), serve=("mission/*/add",), query=("planner/plan", "planner/graph", "mission/*/add"),
                    watch=("alive/**",)),
}


def access_control(roles: dict[str, Role] = ROLES) -> dict[str, Any]:
    """The router's `access_control` block: one subject (its user name) and one policy per role."""
    rules: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for name, role in roles.items():
        ids = []
        for cap, keys in role.grants(name).items():
            for flow, messages in CAPABILITIES[cap]:
                ids.append(f"{name}:{cap}:{flow}")
                rules.append({"id": ids[-1], "permission": "allow", "flows": [flow], "messages": list(messages),
                              "key_exprs": [f"fleet/*/{k}" for k in keys]})
        policies.append({"id": name, "subjects": [name], "rules": ids})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": [{"id": name, "usernames": [name]} for name in roles], "policies": policies}


def router_config(roles: dict[str, Role] = ROLES) -> dict[str, Any]:
    """The whole router configuration: endpoints, the fleet's lease, authentication, access control."""
    return {
        "mode": "router",
        "listen": {"endpoints": ["tcp/0.0.0.0:7447"]},
        "scouting": {"multicast": {"enabled": False}, "delay": 0},
        "transport": {
            "link": {"tx": {"lease": LEASE_MS, "keep_alive": KEEP_ALIVE}},
            "auth": {"usrpwd": {"dictionary_file": USERS_FILE_IN_CONTAINER}},
        },
        "access_control": access_control(roles),
    }


HEADER = """\
// The fleet's zenoh router: user-password authentication (one user per role) and access control.
// Generated from common/deploy/acl.py (`python -m common.deploy.acl > deploy/router.json5`): edit the table there.
// The dictionary file ("user:password" lines) is a secret made at deploy time (`fleet credentials DIR`),
// mounted at the path below; `fleet router --users FILE` points elsewhere. See docs/security.md.
"""


def _dump(value: Any, indent: str = "") -> str:
    """JSON, one line per value that fits in 110 columns (a rule per line), else one per item."""
    flat = json.dumps(value)
    if len(indent) + len(flat) <= 110 or not isinstance(value, dict | list):
        return flat
    inner = indent + "  "
    if isinstance(value, dict):
        items = [f"{inner}{json.dumps(k)}: {_dump(v, inner)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + f"\n{indent}}}"
    return "[\n" + ",\n".join(inner + _dump(v, inner) for v in value) + f"\n{indent}]"


def render() -> str:
    """The text of deploy/router.json5."""
    return HEADER + _dump(router_config()) + "\n"


if __name__ == "__main__":
    sys.stdout.write(render())
