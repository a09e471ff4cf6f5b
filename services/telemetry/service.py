"""The telemetry recorder: zenoh -> rerun. One recording per mission (`<out>/<mission>.rrd`),
opened when the mission's plans arrive: the map graph (asked of the planner, `planner/graph`),
no-fly zones and obstacles, the planned paths, then live bodies coloured by mode, ground truth,
battery and link quality."""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from common.bus.args import keys_from_args, run_service, zconfig_from_args
from common.bus.messages import GraphReply, GraphRequest, SimTruth, Telemetry, VehiclePlan, VehicleState
from common.bus.process_priority import lower_priority
from common.bus.pubsub import QueryError, query
from common.bus.service import Service
from common.domain.mapfile import load_map
from common.errors import InputError
from services.telemetry.rerun_log import GRPC_PORT, WEB_PORT, FleetRecording, web_viewer_url

log = logging.getLogger(__name__)

GRAPH_TIMEOUT_S = 10.0
"""How long the planner may take to build a map's graph for the recorder."""


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
        self.subscribe(k.all_vehicles("state"), VehicleState, self._on_state, maxlen=4096)
        self.subscribe(k.all_vehicles("telemetry"), Telemetry, self._with_recording(FleetRecording.log_telemetry), maxlen=4096)
        self.subscribe(k.all_sim_truth, SimTruth, self._with_recording(FleetRecording.log_truth), maxlen=4096)
        try:
            await self.stopped()
        finally:
            if self.recording is not None:
                self.recording.close()

    def _on_state(self, state: VehicleState, key: str) -> None:
        """Every mode change reaches the timeline; the rest of the states at most `max_hz`."""
        if self.recording is not None:
            self.recording.log_mode(state)
        self._log_state(state, key)

    def _with_recording(self, log_fn):
        """At most `max_hz` messages per key are drawn: the streams arrive at up to 100 Hz per
        vehicle and the recorder shares the machine with the control loops."""
        def handler(msg, key: str) -> None:
            now = time.monotonic()
            if self.recording is None or now - self._logged_at.get(key, -float("inf")) < self.min_interval:
                return
            self._logged_at[key] = now
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
                                timeout=GRAPH_TIMEOUT_S)
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
