import numpy as np

from agent.localisation import GoalLocaliser, LocalisationConfig
from agent.mapping import GridMap
from agent.segmentation import GoalSegmenter, SegmentationConfig, crop_mask, grabcut_mask
from agent.types import Observation, Pose2D
from tests.helpers.agent_scenes import BOXES, obs_and_ids


def test_matches_on_the_object_become_goal_points_and_outliers_are_clustered_away():
    obs, ids = obs_and_ids()
    on_box = np.argwhere(ids == len(BOXES) - 1)[:, ::-1].astype(np.float32)  # (x, y)
    on_wall = np.argwhere(ids == 3)[:, ::-1].astype(np.float32)  # the east wall at x = 6
    rng = np.random.default_rng(0)
    obs_xy = np.vstack([on_box[rng.choice(len(on_box), 30)], on_wall[rng.choice(len(on_wall), 5)]])
    goal_mask = np.zeros((100, 100), bool)
    goal_mask[20:80, 20:80] = True
    goal_xy = np.vstack([rng.uniform(25, 75, (35, 2))]).astype(np.float32)
    goal_xy[-3:] = [5, 5]  # three matches off the object in the goal image are ignored
    loc = GoalLocaliser(LocalisationConfig(depth_window_px=0))
    added = loc.add_matches(obs, goal_xy, obs_xy, goal_mask, score=20.0)
    assert len(added) == 32
    grid = GridMap()
    cands = loc.candidates(grid)
    assert len(cands) == 2
    best = cands[0]
    assert best.n_points == 30
    assert 2.95 <= best.centroid_xy_m[0] <= 3.65 and abs(best.centroid_xy_m[1]) < 0.35
    assert np.all((best.points_xyz[:, 0] > 2.95) & (best.points_xyz[:, 0] < 3.65))  # on the box
    assert cands[1].n_points == 2 and cands[1].centroid_xy_m[0] > 5.9


def test_blacklisted_cells_drop_points_cell_by_cell():
    obs, ids = obs_and_ids()
    loc = GoalLocaliser()
    loc.add_mask_pixels(obs, ids == len(BOXES) - 1, score=1.0)
    grid = GridMap()
    (cand,) = loc.candidates(grid)
    # blacklist only the left half of the candidate's cells: the rest survives
    left = cand.cells_ij[cand.cells_ij[:, 0] < np.median(cand.cells_ij[:, 0])]
    grid.layers.blacklist[left[:, 0], left[:, 1]] = True
    (rest,) = loc.candidates(grid)
    assert 0 < rest.n_points < cand.n_points
    assert not grid.layers.blacklist[rest.cells_ij[:, 0], rest.cells_ij[:, 1]].any()


def test_a_softly_rejected_candidate_drops_only_evidence_below_tau():
    obs, ids = obs_and_ids()
    loc = GoalLocaliser()
    loc.add_mask_pixels(obs, ids == len(BOXES) - 1, score=40.0)  # potential evidence (tau 75)
    grid = GridMap()
    (cand,) = loc.candidates(grid, detection_score=75.0)
    grid.blacklist_cells(cand.cells_ij, 0.3, layer="potential_blacklist")
    assert loc.candidates(grid, detection_score=75.0) == []
    later = obs_and_ids(Pose2D(0.5, 0.0, 0.0))[0]
    later = Observation(
        rgb=later.rgb,
        depth_m=later.depth_m,
        pose=later.pose,
        intrinsics=later.intrinsics,
        goal_image=later.goal_image,
        step=7,
    )
    loc.add_mask_pixels(later, obs_and_ids(Pose2D(0.5, 0.0, 0.0))[1] == len(BOXES) - 1, score=90.0)  # a detection
    (again,) = loc.candidates(grid, detection_score=75.0)
    assert again.max_score == 90.0 and again.frames == (7,)
    # a hard rejection drops the detection too
    grid.blacklist_cells(again.cells_ij, 0.3)
    assert loc.candidates(grid, detection_score=75.0) == []
    try:
        grid.blacklist_cells(again.cells_ij, 0.3, layer="obstacle")
    except ValueError:
        pass
    else:
        raise AssertionError("blacklist_cells accepted a layer that is not a candidate blacklist")


def test_crop_mask_geometry():
    m = crop_mask(512, 512)
    ys, xs = np.nonzero(m)
    assert xs.min() == 170 and xs.max() == 340 and ys.min() == 170 and ys.max() == 447


def test_grabcut_segments_the_central_object():
    rng = np.random.default_rng(1)
    img = (rng.integers(0, 40, (200, 200, 3)) + np.array([40, 120, 40])).astype(np.uint8)  # green clutter
    yy, xx = np.mgrid[0:200, 0:200]
    obj = (xx - 100) ** 2 / 50**2 + (yy - 110) ** 2 / 40**2 <= 1.0
    img[obj] = (rng.integers(0, 40, (int(obj.sum()), 3)) + np.array([160, 40, 120])).astype(np.uint8)
    m = grabcut_mask(img)
    iou = (m & obj).sum() / (m | obj).sum()
    assert iou > 0.8


def test_oracle_goal_mask_is_injected():
    seg = GoalSegmenter(SegmentationConfig(source="oracle"), oracle=lambda img: np.ones(img.shape[:2], bool))
    assert seg.mask(np.zeros((10, 12, 3), np.uint8)).all()
