"""SLC controllers (paper 002 §III): preconditions C(s), triggers T(c) and the forward simulation Phi
of every drone controller and the UGV primitives, on hand-made maps (0.5 m cells, z = 1 m / 2 m)."""

from __future__ import annotations

import pytest

from common.team import controllers as ctl
from common.team.env import LandmarkSpec, grid_env
from common.team.sensing import Sensing
from common.team.team_model import TeamModel

E, NE, N, W, S = 0, 1, 2, 4, 6

# A corridor (rows 3-4) with its north wall (row 5) open at cols 9-10 onto a deep room, and its
# south wall (row 2) open at cols 5-6 onto another deep room. Rows are listed from y = 0 upwards.
CORRIDOR = [
    "##############",  # 0
    "#............#",  # 1
    "#............#",
    "#............#",
    "#............#",
    "#............#",  # 5
    "#####..#######",  # 6: south wall of the corridor, gap at cols 5-6
    "#............#",  # 7: corridor, the drone flies here
    "#............#",  # 8
    "#########..###",  # 9: north wall, gap at cols 9-10
    "#............#",
    "#............#",
    "#............#",
    "#............#",
    "##############",
]


def sensing(rows, **kw) -> Sensing:
    return Sensing(grid_env(rows, **kw), TeamModel())


@pytest.fixture(scope="module")
def corridor() -> Sensing:
    return sensing(CORRIDOR)


def test_wall_following_stops_where_the_followed_wall_ends(corridor):
    # following the north wall (2 cells away) eastwards: it ends at the gap in col 9
    out = ctl.follow_wall(corridor, 0, 7, 1, "left", E)
    assert out[None] == (7, 9, 8)
    assert ctl.phi(corridor, ctl.DronePose(0, 7, 1), ctl.WallFollowController("left", E)) == ctl.DronePose(0, 7, 9, E)


def test_wall_following_opening_trigger_fires_at_the_first_opening_on_the_other_side(corridor):
    out = ctl.follow_wall(corridor, 0, 7, 1, "left", E)
    assert out[ctl.OPENING_RIGHT] == (7, 5, 4)
    pose = ctl.phi(corridor, ctl.DronePose(0, 7, 1), ctl.WallFollowController("left", E), ctl.OPENING_RIGHT)
    assert (pose.row, pose.col) == (7, 5)
    assert ctl.triggers(ctl.WallFollowController("left", E)) == (ctl.OPENING_RIGHT, ctl.LANDMARK_SIGHTED)
    assert ctl.triggers(ctl.WallFollowController("right", E)) == (ctl.OPENING_LEFT, ctl.LANDMARK_SIGHTED)


def test_wall_following_right_side_and_obstacle_ahead(corridor):
    # westwards along the south wall (on the left, 1 cell away) until the west wall blocks the way
    assert ctl.follow_wall(corridor, 0, 7, 4, "left", W)[None] == (7, 1, 3)
    # westwards along the north wall (on the right, 2 cells away) until its gap at col 10
    assert ctl.follow_wall(corridor, 0, 7, 12, "right", W)[None] == (7, 10, 2)


def test_wall_following_needs_a_wall_in_ir_range():
    s = sensing(["#########", *["#.......#"] * 9, "#########"])
    assert ctl.follow_wall(s, 0, 5, 4, "left", E) == {}  # nearest wall 5 cells (2.5 m) away
    assert ctl.phi(s, ctl.DronePose(0, 5, 4), ctl.WallFollowController("left", E)) is None
    assert ctl.follow_wall(s, 0, 2, 4, "right", E)  # the south wall is 2 cells away


def test_wall_following_landmark_sighted_trigger():
    rows = ["##########", "#........#", "#........#", "##..######", "#........#", "#........#", "##########"]
    lm = LandmarkSpec(id="L", x=0.75, y=0.75, z=1.0)  # in the lower room, seen through the gap
    s = sensing(rows, landmarks=[lm])
    out = ctl.follow_wall(s, 0, 5, 1, "left", E)
    r, c, _ = out[ctl.LANDMARK_SIGHTED]
    assert s.landmarks_seen(0, r, c) & 1 and not s.landmarks_seen(0, r, c - 1) & 1


def test_wall_following_into_an_unsensed_low_obstacle_has_no_intrinsic_end():
    # a 0.9 m partition blocks the drone at z = 1 m (clearance 0.3 m) but the IR beam passes above it
    rows = ["#########", "#...c...#", "#.......#", "#########"]
    s = sensing(rows, legend={"c": 0.9})
    assert not s.drone_free(0, 1, 4) and not s.front_sensed(0, 1, 4)
    out = ctl.follow_wall(s, 0, 1, 1, "right", E)
    assert None not in out
    assert ctl.phi(s, ctl.DronePose(0, 1, 1), ctl.WallFollowController("right", E)) is None
    assert ctl.follow_wall(s, 1, 1, 1, "right", E)[None] == (1, 7, 6)  # at z = 2 m it flies over


def test_goto_landmark_stat_needs_the_landmark_in_view():
    rows = ["############", "#..........#", "#..........#", "#..........#", "#..........#", "#..........#", "############"]
    lm = LandmarkSpec(id="L", x=5.25, y=0.6, z=1.0)  # cell (1, 10)
    s = sensing(rows, landmarks=[lm])
    targets = ctl.stat_targets(s, 0, 1, 3, 0)  # 3.5 m away: in camera range
    assert (1, 9) in targets and (5, 10) not in targets
    assert all(max(abs(r - 1), abs(c - 10)) <= 2 for r, c in targets)
    assert ctl.phi(s, ctl.DronePose(0, 1, 3), ctl.GoToLandmarkStatController(0, (1, 9))) == ctl.DronePose(0, 1, 9)
    assert ctl.stat_targets(s, 0, 1, 1, 0) == []  # 4.5 m away: out of camera range
    assert ctl.phi(s, ctl.DronePose(0, 1, 1), ctl.GoToLandmarkStatController(0, (1, 9))) is None


def test_goto_landmark_dyn_needs_the_ugv_in_range_and_sight():
    rows = ["############", "#..........#", "#..........#", "#..........#", "#######....#", "#..........#", "############"]
    s = sensing(rows)
    ugv = ctl.UgvPose(2, 3)
    targets = ctl.dyn_targets(s, 0, 2, 7, 2, 3)
    assert targets and all(max(abs(r - 2), abs(c - 3)) <= 2 for r, c in targets)
    assert ctl.phi(s, ctl.DronePose(0, 2, 7), ctl.GoToLandmarkDynController((2, 4)), ugv=ugv) == ctl.DronePose(0, 2, 4)
    assert ctl.phi(s, ctl.DronePose(0, 2, 7), ctl.GoToLandmarkDynController((2, 4))) is None  # no UGV
    assert ctl.dyn_targets(s, 0, 5, 2, 2, 3) == []  # behind the wall: no line of sight
    assert ctl.dyn_targets(s, 0, 2, 10, 2, 3) == []  # 3.5 m away: out of camera range


def test_metric_step_only_where_allowed_and_never_through_corners():
    rows = ["#######", "#.....#", "#.#...#", "#.....#", "#######"]
    s = sensing(rows, no_metric=[(2.0, 0.0, 3.5, 2.5)])  # cols 4-6
    assert ctl.metric_target(s, 0, 1, 1, N, 2) == (3, 1)
    assert ctl.metric_target(s, 0, 1, 1, NE, 1) is None  # would cut the corner of the pillar
    assert ctl.metric_target(s, 0, 1, 2, E, 2) is None  # ends in the no-metric zone
    turned = ctl.phi(s, ctl.DronePose(0, 1, 1), ctl.MetricTurnController(N))
    assert turned == ctl.DronePose(0, 1, 1, N)
    assert ctl.phi(s, turned, ctl.MetricStepController(2)) == ctl.DronePose(0, 3, 1, N)
    assert ctl.phi(s, ctl.DronePose(0, 1, 4), ctl.MetricTurnController(N)) is None


def test_altitude_needs_a_free_column():
    s = sensing(["#####", "#.t.#", "#####"], legend={"t": 0.75})
    assert ctl.phi(s, ctl.DronePose(0, 1, 1), ctl.AltitudeController(1)) == ctl.DronePose(1, 1, 1)
    assert ctl.phi(s, ctl.DronePose(1, 1, 2), ctl.AltitudeController(0)) is None  # table below


def test_ugv_primitives_respect_zones_and_corners():
    rows = ["######", "#....#", "#.#..#", "#....#", "######"]
    s = sensing(rows, no_ugv=[(2.0, 0.0, 3.0, 3.0)])  # col 4
    assert ctl.phi_ugv(s, ctl.UgvPose(1, 1, E), ctl.UgvForwardController()) == ctl.UgvPose(1, 2, E)
    assert ctl.phi_ugv(s, ctl.UgvPose(1, 3, E), ctl.UgvForwardController()) is None  # forbidden zone
    assert ctl.phi_ugv(s, ctl.UgvPose(1, 1, NE), ctl.UgvForwardController()) is None  # corner of the pillar
    assert ctl.phi_ugv(s, ctl.UgvPose(1, 1, E), ctl.UgvTurnController(-1)) == ctl.UgvPose(1, 1, 7)
