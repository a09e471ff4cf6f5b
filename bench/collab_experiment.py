"""PAD vs full-dimensional ARA* on the two generated office maps (paper 002, Tables I-II).

    .venv/bin/python bench/collab_experiment.py [--instances 50] [--time-limit 10] [--improve 1]
                                                [--out out/collab_experiment.png]

Prints one table per map with the paper's figures beside ours and saves a PNG (same as
`fleet collab bench`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from services.planner.collab.cli import cmd_bench, register  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="collab_experiment", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command")
    register(sub)
    return cmd_bench(parser.parse_args(["collab", "bench", *(sys.argv[1:] if argv is None else argv)]))


if __name__ == "__main__":
    sys.exit(main())
