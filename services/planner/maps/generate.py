"""Generators of the shipped maps (`fleet map generate NAME`): the town of paper 000 §VII-C, the
125-node map of Fig. 6/7 (`fig6`), an older grid like it (`grid125`, 120 nodes) and a city like
Fig. 8 (about 934 nodes).

The YAML files in maps/ are these generators' output; edit the generator, not the file.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import msgspec
import yaml

from common.domain.mapfile import (
    AirRegion,
    Helipad,
    MapSpec,
    NoFlyZone,
    Obstacle,
    ParkingSpot,
    RoadNode,
    Roads,
)
from common.domain.vehicle_model import Speeds, VehicleModel

SPOT_OFFSET = 0.17  # m from the road: more than an envelope diameter (0.15 m) so parked cars never block it
VEHICLE = VehicleModel(margin=0.03)  # Table II defaults; 3 cm clearance for tracking error
FLEET_VEHICLE = VehicleModel(margin=0.03, speed=Speeds(turn=3.0))
CITY_VEHICLE = VehicleModel(margin=0.05, speed=Speeds(turn=3.0))
"""city934's: the fleet of 32 to 80 that soaks it on one 2-core machine tracks its plans within 1.5
cm RMS but a few cm at worst (late commands on a loaded machine), and two drivers each a little off
on a pass planned 3 cm apart met the proximity stop or each other in most runs; with 5 cm none did
(docs/reliability.md, "Last results")."""
"""The maps the fleet flies (town, city934) also budget each turn at a corner, at half the 6 rad/s
a wheel base turns at (its lag, a slow link's late commands: `services/planner/sipp/turns.py`);
grid125 and fig6 reproduce paper 000's planning figures, which do not."""


class _Roads:
    def __init__(self) -> None:
        self.nodes: dict[str, RoadNode] = {}
        self.two_way: list[tuple[str, str]] = []
        self.spots: list[ParkingSpot] = []

    def add(self, nid: str, x: float, y: float) -> str:
        self.nodes[nid] = RoadNode(round(x, 4), round(y, 4))
        return nid

    def chain(self, ids: Iterable[str], closed: bool = False) -> None:
        ids = list(ids)
        pairs = list(zip(ids, ids[1:], strict=False)) + ([(ids[-1], ids[0])] if closed else [])
        self.two_way.extend(pairs)

    def spot(self, sid: str, road: str, dx: float, dy: float) -> None:
        n = self.nodes[road]
        self.spots.append(ParkingSpot(id=sid, x=round(n.x + dx, 4), y=round(n.y + dy, 4), road=road))

    def roads(self) -> Roads:
        return Roads(nodes=self.nodes, two_way=self.two_way)


def _region(r: _Roads, prefix: str, x0: float) -> None:
    """One road region of the town: a 1.2 m x 1.5 m loop with a cross street and 10 parking spots."""
    xs = [x0 + 0.3 * i for i in range(5)]
    ys = [0.3 + 0.25 * j for j in range(7)]
    loop = [r.add(f"{prefix}b{i}", x, ys[0]) for i, x in enumerate(xs)]
    loop += [r.add(f"{prefix}r{j}", xs[-1], y) for j, y in enumerate(ys[1:-1], 1)]
    loop += [r.add(f"{prefix}t{i}", x, ys[-1]) for i, x in reversed(list(enumerate(xs)))]
    loop += [r.add(f"{prefix}l{j}", xs[0], y) for j, y in reversed(list(enumerate(ys[1:-1], 1)))]
    r.chain(loop, closed=True)
    cross = [f"{prefix}l3"] + [r.add(f"{prefix}c{i}", x, ys[3]) for i, x in enumerate(xs[1:-1], 1)] + [f"{prefix}r3"]
    r.chain(cross)
    for i in (1, 2, 3):
        r.spot(f"{prefix}P{i}", f"{prefix}b{i}", 0, -SPOT_OFFSET)
        r.spot(f"{prefix}P{i + 3}", f"{prefix}t{i}", 0, SPOT_OFFSET)
    r.spot(f"{prefix}P7", f"{prefix}l1", -SPOT_OFFSET, 0)
    r.spot(f"{prefix}P8", f"{prefix}l5", -SPOT_OFFSET, 0)
    r.spot(f"{prefix}P9", f"{prefix}r1", SPOT_OFFSET, 0)
    r.spot(f"{prefix}P10", f"{prefix}r5", SPOT_OFFSET, 0)


def town() -> MapSpec:
    """Paper 000 §VII-C: a 4.2 m x 2.1 m town, two road regions not joined on the ground, airspace
    only over a narrow corridor across the middle (the rest a no-fly zone), a helipad on a building
    in the gap."""
    r = _Roads()
    _region(r, "W", 0.3)
    _region(r, "E", 2.7)
    corridor = (0.7, 1.4)
    return MapSpec(
        name="town",
        description="Paper 000 §VII-C miniature town: two road regions joined only through a flight corridor.",
        size=(4.2, 2.1),
        roads=r.roads(),
        parking=r.spots,
        helipads=[Helipad(id="H1", x=2.1, y=1.05, z=0.2)],
        air=AirRegion(bounds=(0.3, 0.8, 3.8, 1.3), layers=[0.4, 0.7], spacing=0.25),
        no_fly=[
            NoFlyZone(name="south", polygon=[(-0.1, -0.1), (4.3, -0.1), (4.3, corridor[0]), (-0.1, corridor[0])]),
            NoFlyZone(name="north", polygon=[(-0.1, corridor[1]), (4.3, corridor[1]), (4.3, 2.2), (-0.1, 2.2)]),
        ],
        obstacles=[Obstacle(name="building", min=(2.0, 0.95, 0.0), max=(2.2, 1.15, 0.15))],
        vehicle=FLEET_VEHICLE,
        time_step=2.0,
    )


def square(name: str, x: float, y: float, w: float) -> NoFlyZone:
    """A no-fly zone over the square from (x, y) with side w, up to the sky."""
    x2, y2 = round(x + w, 6), round(y + w, 6)
    return NoFlyZone(name=name, polygon=[(x, y), (x2, y), (x2, y2), (x, y2)])


def _grid(r: _Roads, n: int, spacing: float, spots: Callable[[int, int], list[tuple[float, float]]]) -> None:
    ids = [[r.add(f"g{i}_{j}", i * spacing, j * spacing) for j in range(n)] for i in range(n)]
    for i in range(n):
        r.chain(ids[i])
        r.chain([ids[k][i] for k in range(n)])
    for i in range(n):
        for j in range(n):
            for k, (dx, dy) in enumerate(spots(i, j)):
                r.spot(f"P{i}_{j}_{k}", ids[i][j], dx, dy)


def grid125() -> MapSpec:
    """Like paper 000 Fig. 6: a 6 x 6 road grid, 24 parking spots on its rim, two air layers with a
    no-fly zone in the middle; about 125 nodes."""
    n, s = 6, 0.4

    def spots(i: int, j: int) -> list[tuple[float, float]]:
        out = []
        if j == 0:
            out.append((0.0, -SPOT_OFFSET))
        if j == n - 1:
            out.append((0.0, SPOT_OFFSET))
        if i == 0 and 0 < j < n - 1:
            out.append((-SPOT_OFFSET, 0.0))
        if i == n - 1 and 0 < j < n - 1:
            out.append((SPOT_OFFSET, 0.0))
        return out

    r = _Roads()
    _grid(r, n, s, spots)
    side = (n - 1) * s
    mid = side / 2
    return MapSpec(
        name="grid125",
        description="Like paper 000 Fig. 6: road grid, rim parking, two air layers, a central no-fly zone.",
        size=(side, side),
        roads=r.roads(),
        parking=r.spots,
        air=AirRegion(bounds=(0.0, 0.0, side, side), layers=[0.4, 0.8], spacing=s),
        no_fly=[square("tower", mid - 0.3, mid - 0.3, 0.6)],
        vehicle=VEHICLE,
        time_step=4.0,
    )


FIG6_STEP = 2.0  # s: the time step fig6 is laid out on


def fig6() -> MapSpec:
    """Paper 000 Fig. 6/7's 125-node map: a 7 x 7 road grid (0.6 m blocks) with 28 rim parking spots
    and one air layer over it, a no-fly tower over the centre; 49 road + 28 parking + 48 air nodes.

    Laid out on its time step (§V-E) so that its one-time-step graph deviates from no speed: with
    dt = 2 s a road block (0.6 m at 0.1 m/s) is three steps, a parking access (0.2 m) one, a takeoff
    or landing (0.4 m at 0.2 m/s) one, a fly edge (0.6 m at 0.3 m/s, no diagonals) one; the air grid
    lies right over the road grid, so every takeoff rises into a grid node.
    """
    n, s, off = 7, 0.6, 0.2
    speed = VEHICLE.speed
    assert abs(s / speed.fly - FIG6_STEP) < 1e-9 and abs(off / speed.drive - FIG6_STEP) < 1e-9

    def spots(i: int, j: int) -> list[tuple[float, float]]:
        out = []
        if j == 0:
            out.append((0.0, -off))
        if j == n - 1:
            out.append((0.0, off))
        if i == 0:
            out.append((-off, 0.0))
        if i == n - 1:
            out.append((off, 0.0))
        return out

    r = _Roads()
    _grid(r, n, s, spots)
    side = (n - 1) * s
    mid = side / 2
    layer = round(speed.takeoff * FIG6_STEP, 6)
    return MapSpec(
        name="fig6",
        description="Paper 000 Fig. 6/7: 125 nodes; road grid, rim parking, one air layer, a central no-fly tower; "
        "laid out on a 2 s time step.",
        size=(side, side),
        roads=r.roads(),
        parking=r.spots,
        air=AirRegion(bounds=(0.0, 0.0, side, side), layers=[layer], spacing=s, diagonals=False),
        no_fly=[square("tower", mid - 0.2, mid - 0.2, 0.4)],
        vehicle=VEHICLE,
        time_step=FIG6_STEP,
    )


def city934() -> MapSpec:
    """Like paper 000 Fig. 8: a 10 x 10 street grid with 150 parking spots, two air layers and
    three no-fly zones; about 934 nodes."""
    n, s = 10, 0.5

    def spots(i: int, j: int) -> list[tuple[float, float]]:
        corners = [(1, 1), (-1, -1), (1, -1), (-1, 1)]
        k = 1 + (i + j) % 2  # alternate one and two spots per intersection
        return [(dx * SPOT_OFFSET, dy * SPOT_OFFSET) for dx, dy in corners[:k]]

    r = _Roads()
    _grid(r, n, s, spots)
    side = (n - 1) * s

    return MapSpec(
        name="city934",
        description="Like paper 000 Fig. 8: street grid, 150 spots, two air layers, three no-fly zones.",
        size=(side, side),
        roads=r.roads(),
        parking=r.spots,
        air=AirRegion(bounds=(0.0, 0.0, side, side), layers=[0.5, 0.9], spacing=0.25),
        no_fly=[square("hospital", 0.6, 0.6, 0.5), square("school", 3.1, 1.1, 0.5), square("park", 1.6, 3.1, 0.5)],
        vehicle=CITY_VEHICLE,
        time_step=2.0,
    )


GENERATORS: dict[str, Callable[[], MapSpec]] = {"town": town, "fig6": fig6, "grid125": grid125, "city934": city934}


def to_yaml(spec: MapSpec) -> str:
    """The map as YAML, with flow style for short lists so the file stays readable."""
    data = msgspec.to_builtins(spec)
    header = f"# Generated by `fleet map generate {spec.name}` (services/planner/maps/generate.py); format in maps/README.md.\n"
    return header + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=110)
