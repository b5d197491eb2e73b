"""The agent's unit tests that run a whole policy for hundreds of steps (a second or more each
on an idle machine) are marked ``slow``: ``make test-fast`` leaves them out, ``make test`` runs
them. A test may carry ``@pytest.mark.slow`` itself instead of being listed here."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers.marks import mark_slow

SLOW = (
    "test_agent_modes.py::test_the_side_step_gets_out_of_turning_to_and_fro",
    "test_agent_modes.py::test_the_deadline_is_not_checked_before_its_window",
    "test_agent_modes.py::test_collision_marks_are_dropped_before_a_candidate_is_given_up_as_unreachable",
    "test_agent_modes.py::test_a_look_from_the_verify_ring_at_half_tau_confirms_the_candidate",
    "test_agent_modes.py::test_last_resort_goes_back_to_the_rejected_candidate_and_stops_there",
    "test_agent_modes.py::test_without_the_last_resort_the_same_run_stops_exhausted_where_it_stands",
    "test_agent_modes.py::test_the_last_resort_at_the_deadline_goes_back_before_the_budget_runs_out",
    "test_agent_modes.py::test_a_decoy_that_scores_low_from_the_verify_ring_is_still_rejected",
    "test_agent_modes.py::test_look_around_then_explore_then_approach_then_stopped",
    "test_agent_modes.py::test_without_the_deadline_the_same_budget_runs_out_exploring",
    "test_deadline_over_weaker.py::test_it_does_not_act_before_the_deadline",
    "test_deadline_over_weaker.py::test_at_the_deadline_the_better_rejected_candidate_goes_before_a_weaker_potential_one",
    "test_exhausted_recheck.py::test_exhausted_with_nothing_found_the_second_look_finds_the_goal_and_stops_there",
    "test_agent_policy.py::test_given_up_frontiers_are_forgiven_before_exhaustion_but_rejected_candidates_are_not",
    "test_agent_policy.py::test_a_failed_forward_move_is_marked_and_not_repeated",
    "test_agent_reid_gate.py::test_exit_stage_stops_an_unrelated_frame_and_leaves_a_matching_one_untouched",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    mark_slow(items, Path(__file__).parent, SLOW)
