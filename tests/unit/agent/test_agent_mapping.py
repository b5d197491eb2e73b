import dataclasses
import math

import numpy as np

from agent.mapping import GridMap, MappingConfig
from agent.types import Pose2D
from tests.helpers.agent_scenes import observation, room_walls

ROOM = room_walls(-1.0, -2.0, 5.0, 2.0)  # 6 x 4 m room, robot at the origin facing +x


def cell(grid, x, y):
    i, j = grid.xy_to_ij(np.array([[x, y]]))[0]
    return int(i), int(j)


def test_front_wall_is_obstacle_and_floor_is_free():
    grid = GridMap(MappingConfig(depth_stride_px=1))
    grid.update(observation(ROOM, Pose2D()))
    L = grid.layers
    assert L.obstacle[cell(grid, 5.02, 0.0)]
    assert L.obstacle[cell(grid, 5.02, 1.0)]
    # open floor in the view is explored and free
    for x in (2.5, 3.5, 4.5):
        assert L.explored[cell(grid, x, 0.0)] and not L.obstacle[cell(grid, x, 0.0)]
    # the blind zone at the robot's feet (floor visible only from ~1.9 m) is covered by the fan
    assert L.explored[cell(grid, 0.5, 0.0)]
    # behind the robot nothing is known
    assert not L.explored[cell(grid, -0.5, 0.0)]
    # no obstacle inside the room
    inner = grid.xy_to_ij(np.array([[0.0, -1.5], [4.8, 1.5]]))
    assert not L.obstacle[inner[0, 0] : inner[1, 0], inner[0, 1] : inner[1, 1]].any()


def test_obstacle_height_band():
    boxes = ROOM + [(2.0, -0.3, 2.4, 0.3, 0.05), (3.0, 0.8, 3.4, 1.2, 0.5)]
    grid = GridMap(MappingConfig(depth_stride_px=1))
    grid.update(observation(boxes, Pose2D()))
    assert not grid.layers.obstacle[cell(grid, 2.02, 0.0)]  # 5 cm: below the 10 cm band
    assert grid.layers.obstacle[cell(grid, 3.02, 1.0)]  # 50 cm box


def test_far_points_are_kept_and_the_map_grows():
    corridor = [(-1.0, -1.1, 16.0, -1.0, 2.5), (-1.0, 1.0, 16.0, 1.1, 2.5), (15.0, -1.0, 15.1, 1.0, 2.5)]
    grid = GridMap(MappingConfig(initial_size_m=8.0, depth_stride_px=1))
    upd = grid.update(observation(corridor, Pose2D()))
    assert upd.grew and upd.n_beyond_max_depth == 0
    assert grid.layers.obstacle[cell(grid, 15.02, 0.0)]  # the end wall 15 m away
    assert grid.layers.explored[cell(grid, 12.0, 0.0)]


def test_layers_do_not_drift_when_the_map_grows():
    grid = GridMap(MappingConfig(initial_size_m=4.0))
    goal_xy = (1.23, -0.77)
    grid.set_goal_cells(grid.xy_to_ij(np.array([goal_xy])))
    grid.mark_collision(Pose2D(0.0, 0.0, 0.0))
    coll_before = grid.ij_to_xy(np.argwhere(grid.layers.collision))
    grid.ensure_contains((-9.0, -7.0), (8.0, 6.5))
    goal_after = grid.ij_to_xy(np.argwhere(grid.layers.goal))
    assert len(goal_after) == 1
    assert math.dist(goal_after[0], goal_xy) < grid.resolution_m
    np.testing.assert_allclose(
        np.sort(grid.ij_to_xy(np.argwhere(grid.layers.collision)), axis=0), np.sort(coll_before, axis=0), atol=1e-9
    )


def test_collision_mark_is_in_front_of_the_robot():
    grid = GridMap()
    grid.mark_collision(Pose2D(1.0, 1.0, math.pi / 2))  # facing +y
    xy = grid.ij_to_xy(np.argwhere(grid.layers.collision))
    assert len(xy) > 0
    assert np.all(xy[:, 1] > 1.1) and np.all(xy[:, 1] < 1.35)
    assert np.all(np.abs(xy[:, 0] - 1.0) < 0.2)


def test_turning_in_place_covers_the_surroundings():
    grid = GridMap()
    for k in range(12):
        grid.update(observation(ROOM, Pose2D(0.0, 0.0, k * math.radians(30))))
    L = grid.layers
    for x, y in [(0.5, 0.0), (-0.5, 0.0), (0.0, 0.6), (0.0, -0.6), (-0.8, 1.5)]:
        assert L.explored[cell(grid, x, y)], (x, y)
    assert L.obstacle[cell(grid, -0.98, 0.0)] and L.obstacle[cell(grid, 0.0, 2.02)]


def test_visited_marks_the_segment():
    grid = GridMap()
    grid.mark_visited((0.0, 0.0), (0.25, 0.0))
    xy = grid.ij_to_xy(np.argwhere(grid.layers.visited))
    assert xy[:, 0].min() < 0.03 and xy[:, 0].max() > 0.22


def test_the_robot_footprint_clears_misplaced_collision_marks():
    grid = GridMap()
    grid.mark_collision(Pose2D(0.0, 0.0, 0.0))  # band 0.17-0.27 m ahead
    assert grid.layers.collision[cell(grid, 0.22, 0.0)]
    grid.mark_visited((0.0, 0.0), (0.22, 0.0))  # ... but the robot then stood there
    assert not grid.layers.collision[cell(grid, 0.22, 0.0)]
    assert grid.layers.visited[cell(grid, 0.22, 0.0)]


def _interior_obstacles(grid) -> int:
    inner = grid.xy_to_ij(np.array([[0.0, -1.5], [4.8, 1.5]]))
    return int(np.count_nonzero(grid.layers.obstacle[inner[0, 0] : inner[1, 0], inner[0, 1] : inner[1, 1]]))


def test_flying_pixels_are_filtered_before_they_reach_the_map():
    """A stereo camera's flying pixels (isolated readings between two surfaces: on a ray that
    sees the floor, a reading short of it lies above the floor) become phantom obstacles in open
    floor unless filtered: either by the consistency check (a reading off its 3x3 median) or by
    asking several points of a cell in one frame. The real walls stay found with both."""
    obs = observation(ROOM, Pose2D())
    depth = obs.depth_m.copy()
    rows, cols = np.mgrid[0 : depth.shape[0] : 5, 0 : depth.shape[1] : 5]
    floor = depth[rows, cols] < 4.0  # lower rows: the floor in front of the robot
    depth[rows[floor], cols[floor]] *= 0.5
    noisy = dataclasses.replace(obs, depth_m=depth)

    def build(**cfg):
        grid = GridMap(MappingConfig(depth_stride_px=1, **cfg))
        grid.update(noisy)
        return grid

    unfiltered = build(obstacle_min_points=1, depth_consistency=0.0)
    assert _interior_obstacles(unfiltered) > 20  # the flying pixels made phantom obstacles
    for cfg in (
        {"obstacle_min_points": 1, "depth_consistency": 0.05},
        {"obstacle_min_points": 3, "depth_consistency": 0.0},
    ):
        grid = build(**cfg)
        assert _interior_obstacles(grid) == 0, cfg
        assert grid.layers.obstacle[cell(grid, 5.02, 0.0)] and grid.layers.obstacle[cell(grid, 5.02, 1.0)], cfg
    # exact depth: the filters change nothing in this room
    exact = [
        GridMap(MappingConfig(depth_stride_px=1, obstacle_min_points=n, depth_consistency=c))
        for n, c in ((1, 0.0), (3, 0.05))
    ]
    for g in exact:
        g.update(obs)
    assert np.array_equal(exact[0].layers.obstacle, exact[1].layers.obstacle)


EVIDENCE = MappingConfig(depth_stride_px=1)  # obstacle evidence on (cap 3), the default
PHANTOM = (2.5, -0.1, 2.7, 0.1, 0.5)  # a box 2.5 m ahead: in view of a level camera at 1.31 m


def blocked(grid, box) -> bool:
    """Any obstacle cell on the box's footprint (its front face may fall in the cell before)."""
    lo = grid.xy_to_ij(np.array([[box[0] - 0.05, box[1]]]))[0]
    hi = grid.xy_to_ij(np.array([[box[2], box[3]]]))[0]
    return bool(grid.layers.obstacle[lo[0] : hi[0] + 1, lo[1] : hi[1] + 1].any())


def test_an_obstacle_seen_once_is_cleared_when_a_later_frame_sees_the_floor_through_it():
    for cap, cleared in ((3, True), (0, False)):
        grid = GridMap(dataclasses.replace(EVIDENCE, obstacle_evidence_cap=cap))
        grid.update(observation(ROOM + [PHANTOM], Pose2D()))
        assert blocked(grid, PHANTOM)
        grid.update(observation(ROOM, Pose2D()))  # the box is gone: the floor is seen through it
        assert blocked(grid, PHANTOM) != cleared, cap
        assert grid.layers.obstacle[cell(grid, 5.02, 0.0)]  # the wall behind stays


def test_an_obstacle_seen_in_many_frames_needs_as_many_clear_views_up_to_the_cap():
    for seen, needed in ((2, 2), (5, 3)):
        grid = GridMap(EVIDENCE)
        for _ in range(seen):
            grid.update(observation(ROOM + [PHANTOM], Pose2D()))
        for k in range(needed):
            assert blocked(grid, PHANTOM), (seen, k)
            grid.update(observation(ROOM, Pose2D()))
        assert not blocked(grid, PHANTOM), seen


def test_an_obstacle_under_the_field_of_view_is_not_cleared():
    """A low box 1 m ahead is below a level camera's view (the floor shows from about 1.9 m):
    frames from there pass over it, they do not see through it."""
    low = (1.0, -0.1, 1.2, 0.1, 0.3)
    grid = GridMap(EVIDENCE)
    grid.update(observation(ROOM + [low, PHANTOM], Pose2D(-0.9, 0.0, 0.0)))  # both seen from 1.9 m back
    assert blocked(grid, low) and blocked(grid, PHANTOM)
    for _ in range(3):
        grid.update(observation(ROOM, Pose2D(0.0, 0.0, 0.0)))  # nearer: the box is under the view
    assert blocked(grid, low)
    assert not blocked(grid, PHANTOM)  # while the one in view is seen through


def test_an_obstacle_is_not_cleared_beyond_the_clearing_range_or_at_the_first_hit():
    far_box = (3.6, -0.1, 3.8, 0.1, 0.5)
    grid = GridMap(EVIDENCE)  # clear_max_range_m 3.0
    grid.update(observation(ROOM + [far_box], Pose2D()))
    grid.update(observation(ROOM, Pose2D()))
    assert blocked(grid, far_box)  # 3.6 m away: depth too coarse to clear
    grid.update(observation(ROOM, Pose2D(1.0, 0.0, 0.0)))  # 2.6 m away
    assert not blocked(grid, far_box)
