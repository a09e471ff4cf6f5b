"""The MovingAI grid map format (Stern et al. 2019, movingai.com/benchmarks): a header (type,
height, width), the line `map`, then one line per row, `.`/`G`/`S` free and `@`/`O`/`T`/`W` blocked."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.domain.mapfile import read_text
from common.errors import InputError

FREE = set(".GS")
BLOCKED = set("@OTW")


def read_grid(path: str | Path) -> np.ndarray:
    """A `.map` file -> boolean array [row, col], True where free."""
    lines = read_text(Path(path)).splitlines()
    try:
        header = {k: v for k, v in (ln.split(None, 1) for ln in lines[:3])}
        height, width = int(header["height"]), int(header["width"])
        start = lines.index("map") + 1
    except (ValueError, KeyError) as exc:
        raise InputError(str(path), "header", f"not a MovingAI map ({exc})") from None
    rows = lines[start:start + height]
    if len(rows) != height or any(len(r) < width for r in rows):
        raise InputError(str(path), "map", f"expected {height} rows of {width} cells")
    for r, row in enumerate(rows):
        bad = set(row[:width]) - FREE - BLOCKED
        if bad:
            raise InputError(str(path), f"row {r}", f"unknown cell characters {sorted(bad)}")
    return np.array([[c in FREE for c in row[:width]] for row in rows])
