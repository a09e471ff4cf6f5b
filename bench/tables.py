"""Shared helpers of the benchmark scripts: arguments, plain-text tables, PNG figures.

Run the benchmarks from the repository root as modules: `python -m bench.NAME`.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the headless backend)
from matplotlib.figure import Figure  # noqa: E402


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
    fig, axes = plt.subplots(1, ncols, figsize=(width * ncols, height), squeeze=False)
    return fig, list(axes[0])


def save_figure(fig: Figure, out_dir: str | Path, name: str) -> Path:
    """Write `name`.png into `out_dir` (created if needed) and close the figure."""
    path = Path(out_dir) / f"{name}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
