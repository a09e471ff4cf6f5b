"""Map names and files -> Env: the generated office maps, YAML maps (`maps/collab/`), MovingAI grids."""

from __future__ import annotations

from pathlib import Path

from common.errors import InputError
from common.team.env import Env, env_from_spec, load_movingai_map, load_yaml_map
from common.team.officegen import OFFICE_MAPS

MAPS_DIR = Path(__file__).resolve().parents[2] / "maps" / "collab"


def map_names() -> list[str]:
    """Built-in generated maps and the YAML maps shipped in maps/collab/."""
    return sorted({*OFFICE_MAPS, *(p.stem for p in MAPS_DIR.glob("*.yaml"))})


def load_env(name_or_path: str) -> Env:
    """A generated map by name, a shipped YAML map by name, a `.yaml` file or a MovingAI `.map`."""
    if name_or_path in OFFICE_MAPS:
        return env_from_spec(OFFICE_MAPS[name_or_path](), name_or_path)
    path = Path(name_or_path)
    if path.suffix == ".map":
        return load_movingai_map(path)
    if path.suffix in (".yaml", ".yml"):
        return load_yaml_map(path)
    shipped = MAPS_DIR / f"{name_or_path}.yaml"
    if shipped.exists():
        return load_yaml_map(shipped)
    raise InputError(name_or_path, "map", f"unknown map (known: {', '.join(map_names())}, or a .yaml/.map file)")
