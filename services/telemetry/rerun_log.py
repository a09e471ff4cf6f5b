"""Fleet telemetry in rerun: the map graph, no-fly zones and obstacles as 3D geometry, the planned
paths, live bodies coloured by mode, each vehicle's mode as a state timeline, battery and link
quality as time series (one recording per mission, saved as .rrd; optionally a live viewer or the
web viewer too). A blueprint opens the viewer on that layout: the 3D scene, battery and link plots
and the mode timeline."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from common.bus.messages import SimTruth, Telemetry, VehiclePlan, VehicleState
from common.domain.mapfile import MapSpec
from common.domain.planfile import PlanGraph

EDGE_RGB = {"drive": (90, 90, 90), "takeoff": (40, 170, 60), "fly": (60, 120, 220), "land": (240, 150, 40)}
NODE_RGB = {
    "parking": (220, 50, 50), "land": (60, 60, 60), "waypoint": (150, 90, 200), "air": (60, 120, 220),
    "helipad": (240, 200, 0),
}
MODE_RGB = {
    "parked": (150, 150, 150), "driving": (40, 170, 60), "taking_off": (240, 200, 0), "flying": (60, 120, 220),
    "landing": (240, 150, 40), "holding": (160, 80, 200), "hovering": (200, 60, 160), "emergency_landing": (230, 30, 30),
    "stopped": (230, 30, 30), "done": (255, 255, 255),
}
NO_FLY_TOP = 1.2  # m: how high to draw no-fly prisms that reach the sky
WEB_PORT, GRPC_PORT = 9090, 9876
"""Defaults of the web viewer's HTTP port and of the gRPC port it reads the recording from."""
_web_viewer: list[int] = []  # the web viewer's port once served (one per process, across recordings)


def mode_colour(mode: str) -> tuple[int, int, int]:
    return MODE_RGB.get(mode.lower(), (0, 0, 0))


def web_viewer_url(web_port: int = WEB_PORT, grpc_port: int = GRPC_PORT) -> str:
    """The address a browser opens to watch the live recording."""
    return f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}%2Fproxy"


def blueprint(vids: list[str]) -> rrb.Blueprint:
    """The viewer's layout: the 3D scene (map, plans, bodies, ground truth) beside battery voltage
    and link quality plots and the mode timeline of every vehicle in `vids` (query expressions take
    no wildcards in the middle of a path, so each vehicle's series is named)."""
    def series(leaf: str) -> list[str]:
        return [f"+ /vehicles/{vid}/{leaf}" for vid in vids]

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="fleet", origin="/", contents=["+ /map/**", "+ /plan/**", "+ /vehicles/**",
                                                                 "+ /truth/**"]),
            rrb.Vertical(
                rrb.TimeSeriesView(name="battery (V)", origin="/vehicles", contents=series("battery_v")),
                rrb.TimeSeriesView(name="link quality", origin="/vehicles", contents=series("link_quality")),
                rrb.StateTimelineView(name="mode", origin="/vehicles", contents=series("mode")),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class FleetRecording:
    """One rerun recording: static map and plan, then time-stamped vehicle data (epoch seconds)."""

    def __init__(self, recording_id: str, rrd: Path | None = None, viewer: bool = False, web: bool = False,
                 web_port: int = WEB_PORT, grpc_port: int = GRPC_PORT) -> None:
        self.rec = rr.RecordingStream("fleet", recording_id=recording_id)
        sinks: list = []
        if rrd is not None:
            rrd.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(rrd)))
        if viewer:
            self.rec.spawn(connect=False)
            sinks.append(rr.GrpcSink())
        if web:  # the recording is served over gRPC (and still written to `rrd`); the viewer reads it
            sinks.append(rr.GrpcServerSink(bind_ip="127.0.0.1", port=grpc_port))
        if sinks:
            self.rec.set_sinks(*sinks)
        if web and not _web_viewer:
            rr.serve_web_viewer(connect_to=f"rerun+http://127.0.0.1:{grpc_port}/proxy", web_port=web_port,
                                open_browser=False)
            _web_viewer.append(web_port)
        self.body: tuple[float, float] = (0.06, 0.05)
        self.vids: list[str] = []
        self._modes: dict[str, str] = {}
        self.rec.send_blueprint(blueprint(self.vids))

    def log_map(self, graph: PlanGraph, spec: MapSpec | None = None) -> None:
        ids = list(graph.nodes)
        pos = np.array([graph.nodes[n].pos for n in ids])
        kinds = [graph.nodes[n].kind for n in ids]
        self.rec.log("map/nodes", rr.Points3D(pos, colors=[NODE_RGB[k] for k in kinds], radii=0.008), static=True)
        index = {n: i for i, n in enumerate(ids)}
        for kind, rgb in EDGE_RGB.items():
            strips = [pos[[index[u], index[v]]] for u, v, k in graph.edges if k == kind and (k != "fly" or u < v)]
            if strips:
                self.rec.log(f"map/edges/{kind}", rr.LineStrips3D(strips, colors=rgb, radii=0.002), static=True)
        if spec is None:
            return
        for zone in spec.no_fly:
            poly = np.array(zone.polygon + [zone.polygon[0]])
            lo, hi = zone.z[0], min(zone.z[1], NO_FLY_TOP)
            rings = [np.c_[poly, np.full(len(poly), z)] for z in (lo, hi)]
            posts = [np.array([[x, y, lo], [x, y, hi]]) for x, y in zone.polygon]
            self.rec.log(f"map/no_fly/{zone.name}", rr.LineStrips3D(rings + posts, colors=(220, 40, 40), radii=0.004), static=True)
        if spec.obstacles:
            lo = np.array([b.min for b in spec.obstacles])
            hi = np.array([b.max for b in spec.obstacles])
            self.rec.log("map/obstacles", rr.Boxes3D(centers=(lo + hi) / 2, half_sizes=(hi - lo) / 2,
                                                      colors=(120, 120, 120), labels=[b.name for b in spec.obstacles]), static=True)

    def log_vehicle_plan(self, plan: VehiclePlan) -> None:
        """A vehicle's planned path as a static line (re-logging the same plan is harmless)."""
        self.body = (plan.model.radius, plan.model.height)
        if plan.vid not in self.vids:
            self.vids.append(plan.vid)
            self.rec.send_blueprint(blueprint(sorted(self.vids)))
        pts = np.array([s.pos for s in plan.steps])
        self.rec.log(f"plan/{plan.vid}", rr.LineStrips3D([pts], radii=0.003, labels=[plan.vid]), static=True)

    def _at(self, t: float) -> None:
        self.rec.set_time("time", timestamp=t)

    def log_state(self, state: VehicleState) -> None:
        self._at(state.t)
        r, h = self.body
        self.rec.log(f"vehicles/{state.vid}/body", rr.Cylinders3D(
            lengths=[h], radii=[r], centers=[(state.x, state.y, state.z)], colors=[mode_colour(state.mode)],
            labels=[f"{state.vid} {state.mode}"]))
        self.rec.log(f"vehicles/{state.vid}/tracking_error", rr.Scalars(state.tracking_error))
        self.rec.log(f"vehicles/{state.vid}/progress", rr.Scalars(state.step / max(state.steps, 1)))

    def log_mode(self, state: VehicleState) -> None:
        """A vehicle's mode on the state timeline, when it changes (every state may be handed in)."""
        if self._modes.get(state.vid) == state.mode:
            return
        self._modes[state.vid] = state.mode
        self._at(state.t)
        self.rec.log(f"vehicles/{state.vid}/mode", rr.StateChange(state=state.mode))

    def log_truth(self, truth: SimTruth) -> None:
        self._at(truth.t)
        self.rec.log(f"truth/{truth.vid}", rr.Points3D([(truth.x, truth.y, truth.z)], radii=0.01, colors=(0, 0, 0)))

    def log_telemetry(self, tel: Telemetry) -> None:
        self._at(tel.t)
        self.rec.log(f"vehicles/{tel.vid}/battery_v", rr.Scalars(tel.vbat))
        self.rec.log(f"vehicles/{tel.vid}/link_quality", rr.Scalars(tel.link_quality))
        self.rec.log(f"vehicles/{tel.vid}/cmd_rate_hz", rr.Scalars(tel.cmd_rate_hz))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
