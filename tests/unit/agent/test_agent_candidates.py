"""Candidate memory: a cluster's views decide its state; rejected candidates stay in the record."""

import numpy as np

from agent.candidates import CandidateMemory, CandidateState, evaluate
from agent.localisation import GoalLocaliser, LocalisationConfig
from agent.mapping import GridMap
from agent.types import Pose2D
from tests.helpers.agent_scenes import BOXES, obs_and_ids


def _add_view(loc, pose, step, score):
    obs, ids = obs_and_ids(pose)
    obs = type(obs)(
        rgb=obs.rgb, depth_m=obs.depth_m, pose=pose, intrinsics=obs.intrinsics, goal_image=obs.goal_image, step=step
    )
    return loc.add_mask_pixels(obs, ids == len(BOXES) - 1, score)


def test_views_and_states():
    loc = GoalLocaliser(LocalisationConfig())
    # the goal box spans x 3.0-3.6: a detection from the start (3 m from its face), then a
    # weak view from 1.5 m
    assert len(_add_view(loc, Pose2D(0.0, 0.0, 0.0), 0, 80.0))
    (cl,) = loc.candidates(GridMap())
    assert cl.frames == (0,) and cl.id == 0
    v = loc.view(0)
    assert v is not None and v.score == 80.0 and 2.9 < v.distance_m < 3.1  # to the box's near face
    # a detection confirms it, from any distance
    c = evaluate(cl, loc, tau=75.0)
    assert c.state == CandidateState.CONFIRMED and c.best_score == 80.0
    # views below tau alone leave a candidate potential, unless a look from the verify ring confirmed it
    assert evaluate(cl, loc, tau=85.0).state == CandidateState.POTENTIAL
    assert len(_add_view(loc, Pose2D(1.5, 0.0, 0.0), 5, 50.0))
    (cl,) = loc.candidates(GridMap())
    assert cl.frames == (0, 5) and cl.id == 0  # the same candidate, two views
    c = evaluate(cl, loc, tau=85.0)
    assert c.state == CandidateState.POTENTIAL and c.best_score == 80.0 and c.best_score_within(2.0) == 50.0
    assert evaluate(cl, loc, tau=85.0, confirmed_steps=frozenset({5})).state == CandidateState.CONFIRMED


def test_memory_reports_live_and_rejected_candidates():
    loc = GoalLocaliser(LocalisationConfig())
    _add_view(loc, Pose2D(0.0, 0.0, 0.0), 3, 80.0)
    (cl,) = loc.candidates(GridMap())
    mem = CandidateMemory()
    live = [evaluate(cl, loc, 75.0)]
    (info,) = mem.infos(live, (0.0, 0.0))
    assert info.state == "confirmed" and info.n_views == 1 and info.best_score == 80.0
    assert 3.0 < info.distance_m < 3.7
    assert info.why is None
    mem.reject(live[0], (0.0, 0.0), why="unreachable for 10 steps")
    (info,) = mem.infos([], (1.0, 0.0))
    assert info.state == "rejected" and info.id == cl.id and info.distance_m < 2.7
    assert info.why == "unreachable for 10 steps"
    # rejected again: the latest reason
    mem.reject(live[0], (0.0, 0.0), why="no progress for 101 steps")
    assert mem.infos([], (1.0, 0.0))[0].why == "no progress for 101 steps"


def test_rejected_clusters_are_kept_for_the_last_resort_best_evidence_first():
    loc = GoalLocaliser(LocalisationConfig())
    grid = GridMap()
    _add_view(loc, Pose2D(0.0, 0.0, 0.0), 3, 60.0)
    (cl,) = loc.candidates(grid)
    mem = CandidateMemory()
    assert mem.best_rejected() is None
    weak = evaluate(cl, loc, 75.0)
    mem.reject(weak, (0.0, 0.0), grid.ij_to_xy(cl.cells_ij))
    # a second, better-scoring rejected candidate elsewhere (same cluster shape, another id)
    from dataclasses import replace

    other = replace(cl, id=7, max_score=70.0)
    mem.reject(other, (0.0, 0.0), grid.ij_to_xy(cl.cells_ij) + 1.0)
    assert mem.best_rejected() == 7 and mem.best_rejected(exclude=frozenset({7})) == cl.id
    assert mem.best_rejected(exclude=frozenset({7, cl.id})) is None
    # rejecting again keeps the best evidence seen
    mem.reject(replace(other, max_score=10.0), (0.0, 0.0), grid.ij_to_xy(cl.cells_ij) + 1.0)
    assert mem.best_score_of(7) == 70.0
    # the kept cells follow the map when it grows (its origin moves)
    before = grid.ij_to_xy(cl.cells_ij)
    assert grid.ensure_contains((-20.0, -20.0), (1.0, 1.0))
    again = mem.rejected_cluster(cl.id, grid.xy_to_ij)
    assert not np.array_equal(again.cells_ij, cl.cells_ij)
    np.testing.assert_allclose(grid.ij_to_xy(again.cells_ij), before)
    assert again.id == cl.id and again.n_points == cl.n_points
    # without cells a rejection is recorded but not kept as a last resort
    mem2 = CandidateMemory()
    mem2.reject(cl, (0.0, 0.0))
    assert mem2.best_rejected() is None and mem2.infos([], (0.0, 0.0))[0].state == "rejected"
