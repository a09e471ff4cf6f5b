"""compose.yaml -> local processes (`fleet up` / `fleet down`).

This machine has no container engine, so `fleet up` runs each compose service as a local process:
the service's `command` (a leading `fleet` becomes this Python's `-m services.cli`), its `environment`,
`deploy.replicas` copies (each with FLEET_INSTANCE=<service>-<n>), in `depends_on` order. A service
whose image is not ours declares its local stand-in under `x-fleet-local`.
`${VAR:-default}` is interpolated as compose does; `fleet up` sets the *_HOST variables to 127.0.0.1
so that container host names resolve to this machine (and the router listens on it only), and
SECRETS_DIR (the containers' /run/secrets) to FLEET_SECRETS, the host directory of the role
credentials: given, or made in <run dir>/secrets.

What compose itself refuses is refused here too, as an `InputError` naming the field: a dependency
on an undefined service, or on a service whose profiles are all inactive unless the dependency says
`required: false` (compose-go's rule); a secret a service uses that the file does not define.
Both forms of `depends_on` are read (a list of names, or a mapping name -> {condition, required}).
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

from common.bus.keys import check_chunk
from common.deploy.acl import ROUTER_CONFIG
from common.deploy.credentials import ensure_credentials
from common.domain.mapfile import _split_msgspec_error, decode_yaml, read_text
from common.errors import InputError

LOCAL_HOSTS = {"ROUTER_HOST": "127.0.0.1", "SIM_HOST": "127.0.0.1", "LISTEN_HOST": "127.0.0.1"}
_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::?-([^}]*))?\}")


class Deploy(msgspec.Struct, frozen=True):
    replicas: int = 1


class Dependency(msgspec.Struct, frozen=True):
    """The long form of one `depends_on` entry."""

    condition: str = "service_started"
    required: bool = True


class ComposeService(msgspec.Struct, frozen=True):
    """The compose fields `fleet up` uses or checks; other compose keys (image, build, ports,
    devices, network_mode, ...) only matter to a container engine and are ignored here."""

    command: list[str] | str | None = None
    environment: dict[str, str | int | float] | list[str] = {}
    deploy: Deploy = Deploy()
    depends_on: list[str] | dict[str, Dependency] = []
    profiles: list[str] = []
    secrets: list[str | dict[str, Any]] = []
    x_fleet_local: list[str] | None = msgspec.field(default=None, name="x-fleet-local")

    def dependencies(self) -> dict[str, Dependency]:
        if isinstance(self.depends_on, dict):
            return self.depends_on
        return {name: Dependency() for name in self.depends_on}

    def secret_names(self) -> list[str]:
        return [s if isinstance(s, str) else str(s.get("source", "")) for s in self.secrets]


class ComposeFile(msgspec.Struct, frozen=True):
    services: dict[str, ComposeService]
    name: str = "fleet"
    secrets: dict[str, Any] = {}


@dataclass
class Process:
    """One process to start: a compose service replica."""

    service: str
    instance: str
    argv: list[str]
    env: dict[str, str] = field(default_factory=dict)


def interpolate(text: str, env: dict[str, str]) -> str:
    """Compose's ${VAR}, ${VAR:-default} and ${VAR-default}."""
    return _VAR.sub(lambda m: env.get(m.group(1)) or (m.group(2) or ""), text)


def _interpolate_values(value: Any, env: dict[str, str]) -> Any:
    """Interpolate every string value of a parsed compose file, as compose does: after parsing, so
    `${N:-1}` stays the string "1" where it stands (a command argument), not the YAML number 1."""
    if isinstance(value, str):
        return interpolate(value, env)
    if isinstance(value, dict):
        return {k: _interpolate_values(v, env) for k, v in value.items()}
    if isinstance(value, list):
        return [_interpolate_values(v, env) for v in value]
    return value


def local_argv(argv: list[str]) -> list[str]:
    """A container command run here: `fleet ...` becomes this interpreter's `-m services.cli ...`."""
    if argv and argv[0] == "fleet":
        return [sys.executable, "-m", "services.cli", *argv[1:]]
    return argv


def _order(services: dict[str, ComposeService], source: str) -> list[str]:
    done: list[str] = []
    visiting: set[str] = set()

    def visit(name: str) -> None:
        if name in done:
            return
        if name in visiting:
            raise InputError(source, f"services.{name}.depends_on", "dependency cycle")
        visiting.add(name)
        for dep in services[name].dependencies():
            if dep not in services:
                raise InputError(source, f"services.{name}.depends_on", f"unknown service {dep!r}")
            visit(dep)
        visiting.discard(name)
        done.append(name)

    for name in services:
        visit(name)
    return done


def local_env(overrides: dict[str, str] | None, run_dir: Path | None) -> dict[str, str]:
    """Variables for interpolating compose.yaml here: the shipped router configuration by its
    absolute path (FLEET_ROUTER_CONFIG: a process started from another directory, an example run
    anywhere, finds it; in a container it is `deploy/router.json5` under the image's directory), the
    environment, the local hosts, the secrets directory (FLEET_SECRETS, or credentials made in
    run_dir/secrets), then `overrides`."""
    env = {"FLEET_ROUTER_CONFIG": str(ROUTER_CONFIG), **os.environ, **LOCAL_HOSTS, **(overrides or {})}
    if "FLEET_SECRETS" not in env and run_dir is not None:
        env["FLEET_SECRETS"] = str(ensure_credentials(run_dir / "secrets").dir.resolve())
    if "FLEET_SECRETS" in env:
        env = {"SECRETS_DIR": env["FLEET_SECRETS"], **env}
    return env


def load_compose(path: str | Path, overrides: dict[str, str] | None = None,
                 run_dir: Path | None = None, profiles: Iterable[str] = ()) -> list[Process]:
    """Parse compose.yaml into processes, in start order (`run_dir`: where `fleet up` keeps its state).
    A service with `profiles` starts only when one of them is active, as in compose."""
    source = str(path)
    env = local_env(overrides, run_dir)
    raw = _interpolate_values(decode_yaml(read_text(Path(path)), dict, source), env)
    try:  # not strict: compose's strings where numbers and booleans go (replicas: "${N:-2}") are converted
        spec = msgspec.convert(raw, ComposeFile, strict=False)
    except msgspec.ValidationError as exc:
        field, problem = _split_msgspec_error(exc)
        raise InputError(source, field, problem) from None
    procs: list[Process] = []
    active = set(profiles)

    def enabled(name: str) -> bool:
        svc = spec.services[name]
        return not svc.profiles or bool(active & set(svc.profiles))

    for name in _order(spec.services, source):
        svc = spec.services[name]
        if not enabled(name):
            continue
        _check_references(spec, name, enabled, source)
        argv = svc.x_fleet_local if svc.x_fleet_local is not None else svc.command
        if argv is None:
            raise InputError(source, f"services.{name}", "needs `command` (or `x-fleet-local` for foreign images)")
        argv = argv.split() if isinstance(argv, str) else list(argv)
        if not argv:
            raise InputError(source, f"services.{name}.command", "is empty")
        try:
            check_chunk(name, "service name")
        except ValueError as exc:  # it names the replicas' instances and log files
            raise InputError(source, f"services.{name}", str(exc)) from None
        service_env = _environment(svc.environment, source, f"services.{name}.environment")
        if svc.deploy.replicas < 1:
            raise InputError(source, f"services.{name}.deploy.replicas", "must be at least 1")
        for i in range(svc.deploy.replicas):
            instance = name if svc.deploy.replicas == 1 else f"{name}-{i + 1}"
            procs.append(Process(name, instance, local_argv(argv), {**service_env, "FLEET_INSTANCE": instance}))
    return procs


def _check_references(spec: ComposeFile, name: str, enabled: Callable[[str], bool], source: str) -> None:
    """What compose refuses of an enabled service: a required dependency on a service no active
    profile enables, a secret the file does not define."""
    svc = spec.services[name]
    for dep, how in svc.dependencies().items():
        if how.required and not enabled(dep):
            raise InputError(source, f"services.{name}.depends_on",
                             f"{dep} is only in profiles {spec.services[dep].profiles}: activate one, or make the "
                             "dependency `required: false`")
    for secret in svc.secret_names():
        if secret not in spec.secrets:
            raise InputError(source, f"services.{name}.secrets", f"secret {secret!r} is not defined under `secrets:`")


def _environment(environment: dict[str, str | int | float] | list[str], source: str, field: str) -> dict[str, str]:
    """Compose's two forms: a mapping, or a list of VAR=VALUE."""
    if isinstance(environment, dict):
        return {k: str(v) for k, v in environment.items()}
    for item in environment:
        if "=" not in item:
            raise InputError(source, field, f"{item!r} is not VAR=VALUE")
    return dict(item.split("=", 1) for item in environment)
