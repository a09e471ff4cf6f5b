"""A fleet started from the API: compose.yaml's services as local processes (the path `fleet up`
and `fleet demo` take, `common.deploy.local.bring_up`), the router among them."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Mapping
from pathlib import Path

from common.deploy.compose import Process
from common.deploy.local import LocalFleet, bring_up
from common.deploy.radios import load_radios


def gateways_for(procs: list[Process], radios_path: Path) -> list[Process]:
    """compose.yaml's gateways (one per radio of its default radios file) made one per radio of
    `radios_path`, each with the template gateway's role and environment."""
    template = next((p for p in procs if p.service.startswith("gateway")), None)
    if template is None:
        return procs
    cli = template.argv[:template.argv.index("gateway")]
    radios = load_radios(radios_path).radios
    made = [Process("gateway", name, [*cli, "gateway", "--config", str(radios_path), "--radio", name, "--subscribe-each"],
                    {**template.env, "FLEET_INSTANCE": name}) for name in radios]
    return [p for p in procs if not p.service.startswith("gateway")] + made


class LocalStack:
    """Services started here, stopped by `close` (the context of `bring_up`, held open)."""

    def __init__(self, run_dir: Path, fleet: str, radios: Path | None, executors: int, profiles: Iterable[str],
                 only: Iterable[str] | None, overrides: Mapping[str, str], timeout_s: float) -> None:
        env = {"FLEET_NAME": fleet, "FLEET_EXECUTORS": str(executors),
               "FLEET_RECORDINGS": str(run_dir / "recordings"), **overrides}
        adjust = None
        if radios is not None:
            radios = radios.resolve()
            env["FLEET_RADIOS"] = str(radios)
            adjust = lambda procs: gateways_for(procs, radios)  # noqa: E731 - bound to this radios file
        self._stack = contextlib.ExitStack()
        self.local: LocalFleet = self._stack.enter_context(
            bring_up(run_dir, env, profiles=profiles, only=only, adjust=adjust, timeout_s=timeout_s))

    def close(self) -> None:
        self._stack.close()
