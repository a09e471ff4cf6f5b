"""The telemetry recorder: zenoh -> rerun. One recording per mission (`<out>/<mission>.rrd`),
opened when the mission's plans arrive: the map graph (asked of the planner, `planner/graph`),
no-fly zones and obstacles, the planned paths, then live bodies coloured by mode, ground truth,
battery and link quality."""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.bus.args import keys_from_args, run_service, zconfig_from_args
from common.bus.messages import GraphReply, GraphRequest, SimTruth, Telemetry, VehiclePlan, VehicleState
from common.bus.process_priority import lower_priority
from common.bus.pubsub import SERVICE_START_S, QueryError, Subscription, query
from common.bus.service import Service
from common.domain.mapfile import load_map
from common.errors import InputError
from services.telemetry.rerun_log import GRPC_PORT, WEB_PORT, FleetRecording, web_viewer_url

log = logging.getLogger(__name__)

GRAPH_TIMEOUT_S = 10.0
"""How long the planner may take to build a map's graph for the recorder."""
STREAM_BACKLOG = 4096
"""Samples of each stream (states, telemetry, ground truth) waiting to be drawn; beyond, the oldest go."""
TIME_JITTER_S = 1e-3
"""s a sample's time may fall short of the drawing interval and still be drawn (100 Hz stamps are not
exactly 10 ms apart: at 20 Hz every fifth, not every sixth)."""
CATCH_UP_S = 2.0
"""s the recorder may spend at its stop drawing its backlog (`fleet down` kills after 5 s)."""


class TelemetryService(Service):
    def __init__(self, instance: str, *args, out: Path = Path("out/recordings"), viewer: bool = False,
                 web: bool = False, max_hz: float = 20.0, web_port: int = WEB_PORT, grpc_port: int = GRPC_PORT,
                 **kwargs) -> None:
        super().__init__("telemetry", instance, *args, **kwargs)
        if max_hz <= 0:
            raise ValueError("max_hz must be positive")
        self.out = out
        self.min_interval = 1.0 / max_hz
        self._logged_at: dict[str, float] = {}
        self.viewer = viewer
        self.web = web
        self.ports = {"web_port": web_port, "grpc_port": grpc_port}
        self.mission = ""
        self.recording: FleetRecording | None = None
        self.files: list[Path] = []
        self.drawn: set[str] = set()
        self._log_state = self._with_recording(FleetRecording.log_state)

    async def main(self) -> None:
        k = self.keys
        self.subscribe(k.all_vehicles("plan"), VehiclePlan, self._on_plan)
        streams = [(self.subscribe(key, typ, handler, maxlen=STREAM_BACKLOG), handler) for key, typ, handler in (
            (k.all_vehicles("state"), VehicleState, self._on_state),
            (k.all_vehicles("telemetry"), Telemetry, self._with_recording(FleetRecording.log_telemetry)),
            (k.all_sim_truth, SimTruth, self._with_recording(FleetRecording.log_truth)))]
        try:
            await self.stopped()
        finally:
            self._catch_up(streams)
            if self.recording is not None:
                self.recording.close()

    def _catch_up(self, streams: list[tuple[Subscription, Callable[[Any, str], None]]]) -> None:
        """Draw what arrived but was not drawn yet before the recording closes: the recorder runs at
        a lower priority and lags the streams on a busy machine, and a fleet stopped right after a
        mission would otherwise lose the mission's end (its last positions, every vehicle's `done`)."""
        deadline = time.monotonic() + CATCH_UP_S
        for sub, handler in streams:
            backlog = sub.close_and_drain()
            for n, (msg, key) in enumerate(backlog):
                if time.monotonic() > deadline:
                    log.warning("telemetry: %d samples of %s not drawn at the stop", len(backlog) - n, sub.key)
                    break
                handler(msg, key)

    def _on_state(self, state: VehicleState, key: str) -> None:
        """Every mode change reaches the timeline; the rest of the states at most `max_hz`."""
        if self.recording is not None:
            self.recording.log_mode(state)
        self._log_state(state, key)

    def _with_recording(self, log_fn):
        """At most `max_hz` messages per key are drawn: the streams arrive at up to 100 Hz per
        vehicle and the recorder shares the machine with the control loops."""
        def handler(msg, key: str) -> None:
            since = msg.t - self._logged_at.get(key, -math.inf)  # by the sample's own time: a backlog
            if self.recording is None or 0.0 <= since < self.min_interval - TIME_JITTER_S:  # is drawn alike
                return
            self._logged_at[key] = msg.t
            log_fn(self.recording, msg)
        return handler

    def _on_plan(self, plan: VehiclePlan, _key: str) -> None:
        if plan.mission != self.mission:
            self._open(plan)
        assert self.recording is not None
        if plan.vid not in self.drawn:  # the mission runner re-publishes plans every second
            self.drawn.add(plan.vid)
            self.recording.log_vehicle_plan(plan)

    def _open(self, plan: VehiclePlan) -> None:
        if self.recording is not None:
            self.recording.close()
        self.mission = plan.mission
        self.drawn.clear()
        path = self.out / f"{plan.mission or 'no-mission'}.rrd"
        self.recording = FleetRecording(plan.mission or "fleet", path, viewer=self.viewer, web=self.web, **self.ports)
        if self.web:
            log.warning("live view of mission %s: %s", plan.mission, web_viewer_url(**self.ports))
        self.files.append(path)
        self.spawn(self._draw_map(self.recording, plan.map), name=f"map {plan.map}")
        log.info("recording mission %s to %s", plan.mission, path)

    async def _draw_map(self, recording: FleetRecording, map_name: str) -> None:
        """The planner's graph of the map (`planner/graph`) and the map file's zones and obstacles."""
        try:
            reply = await query(self.session, self.keys.planner_graph, GraphRequest(map=map_name), GraphReply,
                                timeout=GRAPH_TIMEOUT_S, find_s=SERVICE_START_S)
            if not reply.ok or reply.graph is None:
                raise InputError(map_name, "", reply.error or "the planner sent no graph")
            recording.log_map(reply.graph, load_map(map_name))
        except (QueryError, InputError) as exc:
            log.warning("telemetry: cannot draw map %s: %s", map_name, exc)


def cmd_telemetry(args: argparse.Namespace) -> int:
    if args.max_hz <= 0:
        raise InputError(f"--max-hz: must be positive, got {args.max_hz}")
    lower_priority(args.nice)
    svc = TelemetryService(args.instance, zconfig_from_args(args), keys_from_args(args),
                           out=args.out, viewer=args.viewer, web=args.web, max_hz=args.max_hz,
                           web_port=args.web_port, grpc_port=args.grpc_port)
    return run_service(svc)
