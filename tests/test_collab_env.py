"""Maps for the ground-air team (002 §V-B): the strict YAML format, MovingAI import, the generated
office maps, and the sensor model built on them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from common.errors import InputError
from common.team.env import load_movingai_map, load_yaml_map
from common.team.maps import load_env, map_names
from common.team.officegen import OFFICE_MAPS
from common.team.sensing import Sensing
from common.team.team_model import TeamModel

MOVINGAI = Path(__file__).resolve().parents[2] / "shared" / "benchmarks" / "movingai"
GOOD = """\
format: fleet-collab-map/1
name: tiny
legend: {c: 0.9}
rows: ["#####", "#.c.#", "#...#", "#####"]
landmarks: [{id: L, x: 1.0, y: 1.0}]
no_ugv: [[0.0, 0.9, 2.5, 2.0]]
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "map.yaml"
    path.write_text(text)
    return path


def test_yaml_map_loads_heights_zones_and_landmarks(tmp_path):
    env = load_yaml_map(write(tmp_path, GOOD))
    assert env.shape == (4, 5) and env.z_levels == (1.0, 2.0)
    assert env.heights[1, 2] == 0.9 and math.isinf(env.heights[0, 0]) and env.heights[2, 1] == 0.0
    assert env.no_ugv[2].tolist() == [True] * 5 and not env.no_ugv[1].any()
    assert env.landmarks[0].z == 1.5 and env.cell_of(1.0, 1.0) == (2, 2)
    assert not env.no_metric.any()


@pytest.mark.parametrize(
    "text,field",
    [
        (GOOD + "colour: red\n", "colour"),  # unknown key
        (GOOD.replace("name: tiny", "name: 3"), "name"),  # wrong type
        (GOOD.replace('"#.c.#"', '"#.x.#"'), "rows[1]"),  # unknown cell character
        (GOOD.replace('"#...#"', '"#..#"'), "rows[2]"),  # ragged grid
        (GOOD.replace("x: 1.0", "x: 9.0"), "landmarks[0]"),
        (GOOD.replace("[[0.0, 0.9, 2.5, 2.0]]", "[[1.0, 0.9, 0.5, 2.0]]"), "no_ugv[0]"),
        (GOOD.replace("fleet-collab-map/1", "fleet-map/1"), "format"),
        (GOOD + "z_levels: [2.0, 1.0]\n", "z_levels"),
    ],
)
def test_bad_yaml_maps_are_input_errors_naming_the_field(tmp_path, text, field):
    with pytest.raises(InputError) as err:
        load_yaml_map(write(tmp_path, text))
    assert err.value.source.endswith("map.yaml") and field in str(err.value)


def test_map_names_and_bad_paths():
    assert {"office-conference", "office-cubicles", "demo-room"} <= set(map_names())
    with pytest.raises(InputError):
        load_env("no-such-map")
    with pytest.raises(InputError):
        load_env("/nonexistent/file.yaml")


@pytest.mark.skipif(not MOVINGAI.is_dir(), reason="MovingAI benchmark files not present")
def test_movingai_maps_import_as_walls():
    env = load_movingai_map(MOVINGAI / "room-32-32-4.map")
    assert env.shape == (32, 32) and env.name == "room-32-32-4"
    assert math.isinf(env.heights[0, 0]) and env.heights[1, 1] == 0.0  # '@' and '.'
    assert load_env(str(MOVINGAI / "empty-8-8.map")).heights.sum() == 0.0
    with pytest.raises(InputError):
        load_movingai_map(MOVINGAI / "random-32-32-10-random-1.scen")


def test_office_maps_are_deterministic_and_match_the_paper_layout():
    for name, make in OFFICE_MAPS.items():
        a, b = make(), make()
        assert a == b
        env = load_env(name)
        assert env.shape == (40, 64) and env.no_ugv.any() and env.no_metric.any()
        s = Sensing(env, TeamModel())
        hallway = env.no_ugv & ~s.blocked[0]
        assert hallway.any() and not (hallway & s.ugv_free).any()  # the UGV stays out of hallways
        assert not any(env.no_ugv[env.cell_of(lm.x, lm.y)] for lm in env.landmarks)  # featureless hallways
        seen = [s.landmarks_seen(k, r, c) > 0 for k in (0, 1) for r, c in np.argwhere(hallway)]
        assert np.mean(seen) < 0.05  # at most glimpses through doors


def test_cubicle_partitions_block_the_drone_low_but_not_its_ir_sensors():
    env = load_env("office-cubicles")
    s = Sensing(env, TeamModel())
    partitions = env.heights == 0.9
    assert s.blocked[0][partitions].all() and not s.sensed[0][partitions].any()
    assert not s.blocked[1][partitions].any()  # the drone flies over them at 2 m


def test_ugv_sighting_is_line_of_sight_in_3d():
    env = load_env("demo-room")
    s = Sensing(env, TeamModel())
    assert s.sees_ugv(1, 3, 3, 2, 1)
    assert not s.sees_ugv(1, 3, 20, 3, 13)  # through the wall between room and hallway
    assert not s.sees_ugv(1, 10, 10, 1, 1)  # beyond camera range
