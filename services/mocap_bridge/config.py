"""The mocap bridge's configuration (docs/mocap.md), a YAML file decoded strictly, or the defaults
(the simulated motion capture of `fleet sim`, every simulated vehicle at 100 Hz; its noise is the
radios file's `mocap` model).

```yaml
backend: vicon                  # sim (fleet sim's frames) | mock | vicon | optitrack | qualisys | vrpn
options: {hostname: 10.0.0.5}   # passed to motioncapture.connect (strings)
rate_hz: 100                    # most poses per second per body
bodies: {cf_01: cf1, cf_02: cf2}   # rigid-body name -> vehicle id (empty: the body's name is the vid)
lost_after_s: 0.1               # a body unseen this long is reported lost
latency_s: 0.0                  # real systems: subtracted from the arrival time for the capture stamp
max_age_s: 0.1                  # a frame captured longer ago when the bridge gets to it is dropped
```
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import msgspec

from common.bus.keys import check_chunk
from common.domain.mapfile import decode_yaml, read_text
from common.errors import InputError

_Strict = {"frozen": True, "forbid_unknown_fields": True}
Positive = Annotated[float, msgspec.Meta(gt=0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0)]

Backend = Literal["sim", "mock", "vicon", "optitrack", "qualisys", "vrpn"]
LIB_BACKENDS: tuple[str, ...] = ("mock", "vicon", "optitrack", "qualisys", "vrpn")
"""Backends served by the `motioncapture` library (libmotioncapture)."""


class MocapConfig(msgspec.Struct, **_Strict):
    backend: Backend = "sim"
    options: dict[str, str] = {}
    rate_hz: Positive = 100.0
    bodies: dict[str, str] = {}
    lost_after_s: Positive = 0.1
    latency_s: NonNegative = 0.0
    max_age_s: Positive = 0.1


def check_mocap(config: MocapConfig, source: str) -> None:
    """Every mapped vehicle id is a key chunk, and no vehicle is mapped from two bodies."""
    seen: dict[str, str] = {}
    for body, vid in config.bodies.items():
        try:
            check_chunk(vid, "vehicle id")
        except ValueError as exc:
            raise InputError(source, f"bodies.{body}", str(exc)) from None
        if vid in seen:
            raise InputError(source, f"bodies.{body}", f"vehicle {vid} already mapped from body {seen[vid]}")
        seen[vid] = body


def load_mocap(path: str | Path) -> MocapConfig:
    path = Path(path)
    config: MocapConfig = decode_yaml(read_text(path), MocapConfig, str(path))
    check_mocap(config, str(path))
    return config
