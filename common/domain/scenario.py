"""The scenario file (paper 000 §IV): vehicle id -> start and goal, and optionally the map
(maps/scenarios/*.yaml). Planners check it against the map's graph (`services/planner/maps/tasks.py`)."""

from __future__ import annotations

from pathlib import Path

import msgspec

from common.domain.mapfile import decode_yaml, read_text
from common.domain.planfile import Task


class ScenarioFile(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    tasks: dict[str, Task]
    map: str | None = None
    description: str = ""


def read_scenario(path: str | Path) -> ScenarioFile:
    """Decode a scenario file strictly (InputError naming the file and field)."""
    return decode_yaml(read_text(Path(path)), ScenarioFile, str(path))
