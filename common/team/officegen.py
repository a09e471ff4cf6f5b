"""The two generated office maps of the experiments (002 §V-B, Fig. 5), deterministic from a seed.

`office-conference`: two large conference rooms with tables, an outdoor patio with planters, and
hallways with small offices. `office-cubicles`: a cluster of cubicles (low partitions the drone's
side IR sensors fly above), desks, boxes and shelves in one half, featureless hallways in the
other. As in 002 §V-B the UGV is kept out of the hallways (and offices), GOTOLANDMARK controllers
are useless there (no landmarks, no UGV), and the drone needs the UGV to cross the cluttered parts.
Both are 32 m x 20 m at 0.5 m cells.
"""

from __future__ import annotations

import numpy as np

from common.team.env import LandmarkSpec, TeamMapSpec

WIDTH, HEIGHT, RES = 64, 40, 0.5
LEGEND = {
    "t": 0.75,  # table or desk
    "c": 0.9,  # cubicle partition
    "k": 0.6,  # planter, bench
    "b": 1.2,  # stacked boxes
    "e": 2.2,  # shelf, equipment
}


class _Canvas:
    """A character grid [row = y, col = x] with rectangle drawing."""

    def __init__(self) -> None:
        self.g = np.full((HEIGHT, WIDTH), ".", dtype="<U1")
        self.g[0, :] = self.g[-1, :] = "#"
        self.g[:, 0] = self.g[:, -1] = "#"

    def fill(self, r0: int, r1: int, c0: int, c1: int, ch: str) -> None:
        """Rows r0..r1 and cols c0..c1, inclusive."""
        self.g[r0:r1 + 1, c0:c1 + 1] = ch

    def rows(self) -> list[str]:
        return ["".join(row) for row in self.g]


def _landmarks(points: list[tuple[float, float]]) -> list[LandmarkSpec]:
    return [LandmarkSpec(id=f"L{i}", x=x, y=y, z=1.5) for i, (x, y) in enumerate(points)]


def conference_map() -> TeamMapSpec:
    """Conference rooms and patio (002 Fig. 5a)."""
    cv = _Canvas()
    cv.fill(18, 18, 0, 63, "#")  # rooms | hallway
    for c0 in (10, 33, 54):  # doors of room A, room B, patio
        cv.fill(18, 18, c0, c0 + 1, ".")
    cv.fill(0, 18, 23, 23, "#")  # room A | room B, wide opening
    cv.fill(7, 10, 23, 23, ".")
    cv.fill(0, 18, 44, 44, "#")  # room B | patio, glass doors
    cv.fill(3, 5, 44, 44, ".")
    cv.fill(7, 10, 6, 17, "t")  # conference tables
    cv.fill(7, 10, 28, 39, "t")
    for r0, c0 in ((4, 49), (11, 50), (6, 57), (13, 58)):  # planters on the patio
        cv.fill(r0, r0 + 1, c0, c0 + 1, "k")
    cv.fill(22, 22, 0, 63, "#")  # hallway 1 | offices row 1
    cv.fill(29, 29, 0, 63, "#")  # offices row 1 | hallway 2
    cv.fill(33, 33, 0, 63, "#")  # hallway 2 | offices row 2
    cv.fill(22, 29, 1, 2, ".")  # end corridors joining the two hallways
    cv.fill(22, 29, 61, 62, ".")
    cv.fill(23, 28, 3, 3, "#")
    cv.fill(23, 28, 60, 60, "#")
    for c in range(11, 60, 8):  # office walls
        cv.fill(23, 28, c, c, "#")
        cv.fill(34, 38, c, c, "#")
    for c in range(6, 60, 8):  # office doors
        cv.fill(22, 22, c, c + 1, ".")
        cv.fill(33, 33, c, c + 1, ".")
    lms = _landmarks([(0.6, 4.5), (8.0, 0.6), (3.0, 8.9), (16.0, 0.6), (21.4, 4.0), (26.0, 4.0), (29.5, 7.5)])
    return TeamMapSpec(
        format="fleet-collab-map/1",
        name="office-conference",
        rows=cv.rows(),
        resolution=RES,
        legend=LEGEND,
        landmarks=lms,
        no_ugv=[(0.0, 9.0, 32.0, 20.0)],
        no_metric=[(0.0, 0.0, 22.0, 9.0)],
    )


def cubicles_map(seed: int = 7) -> TeamMapSpec:
    """Cubicles and hallways (002 Fig. 5b); `seed` makes the cubicles erratic but reproducible."""
    rng = np.random.default_rng(seed)
    cv = _Canvas()
    cv.fill(0, 39, 32, 32, "#")  # cubicles | hallways
    for r0 in (2, 18, 34):
        cv.fill(r0, r0 + 2, 32, 32, ".")
    for r0 in range(3, 32, 7):  # 5 x 4 cubicles of 2.5 m with 1 m aisles
        for c0 in range(3, 28, 7):
            r1, c1 = r0 + 4, c0 + 4
            cv.fill(r0, r1, c0, c1, "c")
            cv.fill(r0 + 1, r1 - 1, c0 + 1, c1 - 1, ".")
            side = rng.integers(4)
            at = int(rng.integers(1, 3))
            if side == 0:
                cv.fill(r0, r0, c0 + at, c0 + at + 1, ".")
                cv.fill(r1 - 1, r1 - 1, c0 + 1, c1 - 1, "t")
            elif side == 1:
                cv.fill(r1, r1, c0 + at, c0 + at + 1, ".")
                cv.fill(r0 + 1, r0 + 1, c0 + 1, c1 - 1, "t")
            elif side == 2:
                cv.fill(r0 + at, r0 + at + 1, c0, c0, ".")
                cv.fill(r0 + 1, r1 - 1, c1 - 1, c1 - 1, "t")
            else:
                cv.fill(r0 + at, r0 + at + 1, c1, c1, ".")
                cv.fill(r0 + 1, r1 - 1, c0 + 1, c0 + 1, "t")
    for _ in range(10):  # boxes against partitions, never closing an aisle
        r, c = int(rng.integers(3, 36)), int(rng.integers(3, 29))
        if cv.g[r, c] == "c" and (r - 3) % 7 in (0, 4):
            rr = r - 1 if (r - 3) % 7 == 0 else r + 1
            cv.fill(rr, rr, c, c, "b")
    cv.fill(37, 38, 8, 12, "e")  # shelves along the far wall
    cv.fill(37, 38, 20, 23, "e")
    cv.fill(33, 39, 33, 63, "#")  # hallways: solid blocks, 1.5 m corridors carved out
    cv.fill(1, 32, 33, 62, "#")
    for r0 in (2, 18, 34):
        cv.fill(r0, r0 + 2, 33, 62, ".")
    for c0 in (35, 47, 59):
        cv.fill(2, 36, c0, c0 + 2, ".")
    lms = _landmarks([(0.6, 6.0), (0.6, 14.0), (8.0, 19.4)])
    return TeamMapSpec(
        format="fleet-collab-map/1",
        name="office-cubicles",
        rows=cv.rows(),
        resolution=RES,
        legend=LEGEND,
        landmarks=lms,
        no_ugv=[(16.0, 0.0, 32.0, 20.0)],
        no_metric=[(0.0, 0.0, 16.0, 20.0)],
    )


OFFICE_MAPS = {"office-conference": conference_map, "office-cubicles": cubicles_map}
