"""Shared helpers of the benchmark scripts: arguments, plain-text tables, PNG figures, the machine's
speed.

Run the benchmarks from the repository root as modules: `python -m bench.NAME`.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


def pyplot() -> ModuleType:
    """matplotlib's pyplot on its headless backend, imported on first use: it takes about 0.3 s
    (0.7 s on a loaded machine), and a benchmark's own worker processes (`bench.router_hop`'s
    publisher and subscribers) draw nothing."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def bench_parser(description: str) -> argparse.ArgumentParser:
    """An argument parser with the options every benchmark shares: --out (directory of the PNG)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--out", default="out", help="directory for the figure (default: out/)")
    return parser


def format_table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """Right-aligned columns; floats as given by the caller (format them before)."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def new_figure(ncols: int = 1, width: float = 5.0, height: float = 3.6) -> tuple[Figure, list]:
    fig, axes = pyplot().subplots(1, ncols, figsize=(width * ncols, height), squeeze=False)
    return fig, list(axes[0])


def plot_series(ax: Axes, xs: Sequence[float], series: Mapping[str, Sequence[float]], **labels: str) -> None:
    """One line per series (its label -> its values over `xs`), markers in turn, with a legend and
    the axes' `labels` (`xlabel`, `ylabel`, `title`)."""
    for (label, ys), marker in zip(series.items(), "os^vD*", strict=False):
        ax.plot(xs, ys, f"{marker}-", label=label)
    ax.set(**labels)
    ax.legend()


def save_figure(fig: Figure, out_dir: str | Path, name: str) -> Path:
    """Write `name`.png into `out_dir` (created if needed) and close the figure."""
    path = Path(out_dir) / f"{name}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    pyplot().close(fig)
    return path


PROBE_N = 2_000_000


def cpu_probe() -> tuple[float, float]:
    """A fixed pure-Python loop: (wall time, this thread's CPU time) in ms. The machine's speed as
    the fleet's Python sees it, so that figures taken on different hours can be told apart: the
    CPU time is the core's speed, the wall time adds what other machines' work on the host took
    from it (the 2-core machine of 2026-12-06 gave 232-246 ms of both in one night, whether a
    32-vehicle soak's fleet kept up or not)."""
    wall, cpu = time.perf_counter(), time.thread_time()
    sum(i * i for i in range(PROBE_N))
    return 1e3 * (time.perf_counter() - wall), 1e3 * (time.thread_time() - cpu)
