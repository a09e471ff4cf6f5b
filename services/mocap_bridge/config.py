"""The mocap bridge's configuration (docs/mocap.md), a YAML file decoded strictly, or the defaults
(the simulated motion capture of `fleet sim`, every simulated vehicle at 100 Hz; its noise is the
radios file's `mocap` model).

```yaml
backend: vicon                  # sim (fleet sim's frames) | mock | vicon | optitrack | qualisys | vrpn
options: {hostname: 10.0.0.5}   # passed to motioncapture.connect (strings)
rate_hz: 100                    # most poses per second per body (in the frames on mocap/frame)
vehicle_pose_hz: 20             # poses per second per body on vehicle/<vid>/pose (tools, recorder)
bodies: {cf_01: cf1, cf_02: cf2}   # rigid-body name -> vehicle id (empty: the body's name is the vid)
lost_after_s: 0.1               # a body unseen this long is reported lost
latency_s: 0.0                  # real systems: subtracted from the arrival time for the capture stamp
max_age_s: 0.25                 # a frame captured longer ago when the bridge gets to it is dropped
startup_wait_s: 10              # at start, wait this long for every mapped body, then name the missing
frame: {up: z, origin: [0, 0, 0], yaw_deg: 0}   # the system's frame -> the map's (frame.py)
```

A rigid body named twice in `bodies` (YAML would keep only the last) and a vehicle mapped from two
bodies are errors naming the field.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

import msgspec
import yaml

from common.bus.keys import check_chunk
from common.domain.mapfile import decode_yaml, read_text
from common.errors import InputError

_Strict = {"frozen": True, "forbid_unknown_fields": True}
Positive = Annotated[float, msgspec.Meta(gt=0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0)]

Backend = Literal["sim", "mock", "vicon", "optitrack", "qualisys", "vrpn"]
LIB_BACKENDS: tuple[str, ...] = ("mock", "vicon", "optitrack", "qualisys", "vrpn")
"""Backends served by the `motioncapture` library (libmotioncapture)."""


class FrameSpec(msgspec.Struct, **_Strict):
    """The system's frame -> the map's (`services.mocap_bridge.frame`): `up` the system's up axis;
    `origin` the map's origin in the system's coordinates (m); `yaw_deg` the map's +x axis, degrees
    CCW seen from above from the system's +x axis."""

    up: Literal["z", "y"] = "z"
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_deg: float = 0.0


class MocapConfig(msgspec.Struct, **_Strict):
    backend: Backend = "sim"
    options: dict[str, str] = {}
    rate_hz: Positive = 100.0
    vehicle_pose_hz: Positive = 20.0
    bodies: dict[str, str] = {}
    lost_after_s: Positive = 0.1
    latency_s: NonNegative = 0.0
    max_age_s: Positive = 0.25
    startup_wait_s: NonNegative = 10.0
    frame: FrameSpec = FrameSpec()


def check_mocap(config: MocapConfig, source: str) -> None:
    """Every mapped vehicle id is a key chunk, no vehicle is mapped from two bodies, the frame is
    finite and only given for a real system (the simulated one streams map coordinates)."""
    frame = config.frame
    for field, values in (("frame.origin", frame.origin), ("frame.yaw_deg", (frame.yaw_deg,))):
        if not all(math.isfinite(v) for v in values):
            raise InputError(source, field, "must be finite")
    if config.backend == "sim" and frame != FrameSpec():
        raise InputError(source, "frame", "the sim backend streams map coordinates: no frame to give")
    seen: dict[str, str] = {}
    for body, vid in config.bodies.items():
        try:
            check_chunk(vid, "vehicle id")
        except ValueError as exc:
            raise InputError(source, f"bodies.{body}", str(exc)) from None
        if vid in seen:
            raise InputError(source, f"bodies.{body}", f"vehicle {vid} already mapped from body {seen[vid]}")
        seen[vid] = body


def check_unique_keys(text: str, source: str) -> None:
    """A key given twice in one mapping of a YAML text (which YAML loaders resolve silently, the last
    one winning) is an InputError naming it and both lines; in `bodies`, a rigid body named twice."""

    def walk(node: yaml.Node, where: str) -> None:
        if isinstance(node, yaml.MappingNode):
            lines: dict[object, int] = {}
            for key, value in node.value:
                name = key.value if isinstance(key, yaml.ScalarNode) else str(key.start_mark)
                field = f"{where}.{name}" if where else str(name)
                if name in lines:
                    what = "rigid body" if where == "bodies" else "key"
                    raise InputError(source, field, f"{what} {name} named twice (lines {lines[name]} and "
                                                    f"{key.start_mark.line + 1}): YAML keeps only the last")
                lines[name] = key.start_mark.line + 1
                walk(value, field)
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                walk(item, f"{where}[{i}]")

    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return  # decode_yaml names the problem
    if root is not None:
        walk(root, "")


def load_mocap(path: str | Path) -> MocapConfig:
    path = Path(path)
    text = read_text(path)
    config: MocapConfig = decode_yaml(text, MocapConfig, str(path))
    check_unique_keys(text, str(path))
    check_mocap(config, str(path))
    return config
