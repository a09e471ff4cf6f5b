"""Read a mission's rerun recording back with the rerun SDK (no viewer): for every vehicle, how far
its body moved, the modes it went through and its battery voltage. Recordings are written by the
fleet's telemetry recorder, one per mission (`fleet demo`: out/demo/recordings/*.rrd).

    python examples/read_recording.py [RECORDING.rrd]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from rerun.chunk import RrdReader


def _chunks(path: Path, tries: int = 5) -> list:
    """Every chunk of the file, read eagerly; a recording still being written may end in a
    half-written message: read it again a moment later (the recorder completes it)."""
    for attempt in range(tries):
        try:
            return list(RrdReader(str(path)).stream().collect().stream())
        except Exception:  # the reader's error for a truncated message
            if attempt == tries - 1:
                raise
            time.sleep(0.5)
    return []


def read(path: Path) -> dict[str, dict[str, list]]:
    """vehicle -> {"body": [(t_ns, x, y, z)], "mode": [(t_ns, mode)], "battery_v": [(t_ns, volts)]}."""
    out: dict[str, dict[str, list]] = {}
    columns = {"body": "Cylinders3D:centers", "mode": "StateChange:state", "battery_v": "Scalars:scalars"}
    # eagerly: the recorder keeps a mission's file open (no footer yet) until the next mission begins
    for chunk in _chunks(path):
        parts = chunk.entity_path.strip("/").split("/")
        if len(parts) != 3 or parts[0] != "vehicles" or parts[2] not in columns:
            continue
        batch = chunk.to_record_batch()
        if "time" not in batch.schema.names or columns[parts[2]] not in batch.schema.names:
            continue
        times = batch.column("time").cast("int64").to_pylist()
        values = batch.column(columns[parts[2]]).to_pylist()
        rows = out.setdefault(parts[1], {"body": [], "mode": [], "battery_v": []})[parts[2]]
        rows.extend((t, *v[0]) if parts[2] == "body" else (t, v[0]) for t, v in zip(times, values, strict=True))
    for series in out.values():
        for rows in series.values():
            rows.sort()
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", nargs="?", help="an .rrd file (default: the newest under out/demo/recordings)")
    args = parser.parse_args()
    path = Path(args.recording) if args.recording else max(Path("out/demo/recordings").glob("*.rrd"),
                                                           key=lambda p: p.stat().st_mtime, default=None)
    if path is None or not path.exists():
        print("no recording: run `make demo` first, or name an .rrd file", file=sys.stderr)
        return 1
    vehicles = read(path)
    print(f"{path}: {len(vehicles)} vehicles")
    for vid, series in sorted(vehicles.items()):
        body = np.array([row[1:] for row in series["body"]])
        moved = float(np.linalg.norm(np.diff(body, axis=0), axis=1).sum()) if len(body) > 1 else 0.0
        modes = [m for _, m in series["mode"]]
        volts = [v for _, v in series["battery_v"]]
        battery = f"{min(volts):.2f}-{max(volts):.2f} V" if volts else "-"
        print(f"{vid:<6} {len(body):>5} poses, moved {moved:5.2f} m, highest {body[:, 2].max() if len(body) else 0:.2f} m, "
              f"battery {battery}, modes {' > '.join(modes)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
