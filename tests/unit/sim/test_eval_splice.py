"""sim.evaluation.splice: re-run episodes replace the base's only where the change can act."""

import json

import pytest

from sim.evaluation.splice import main, missing_reruns, same_until_base_end, splice


def rec(eid, actions, final_mode, success=False, home=1):
    poses, x = [[0.0, 0.0, 0.0]], 0.0
    for a in actions:
        x += 0.25 if a == "MOVE_FORWARD" else 0.0
        poses.append([x, 0.0, 0.0])
    return {
        "episode_id": eid,
        "scene_seed": home,
        "agent": "oracle",
        "category": "bed",
        "success": success,
        "spl": 0.5 if success else 0.0,
        "ne": 0.2 if success else 3.0,
        "steps": len(actions),
        "max_steps_reached": False,
        "called_stop": actions[-1:] == ["STOP"],
        "path_length_m": x,
        "shortest_path_m": 1.0,
        "difficulty": "easy",
        "trajectory": {"poses_world": poses, "actions": actions},
        "modiin": {"final_mode": final_mode},
    }


F, L, S = "MOVE_FORWARD", "TURN_LEFT", "STOP"
BASE = [rec("e0", [F, L, S], "exhausted"), rec("e1", [F, F, S], "stopped", success=True, home=2)]


def test_a_rerun_that_repeats_the_base_until_its_end_replaces_it():
    rerun = [rec("e0", [F, L, F, F, S], "stopped", success=True)]
    assert same_until_base_end(BASE[0], rerun[0]) is None
    out = splice(BASE, rerun, "exhausted")
    assert [r["episode_id"] for r in out] == ["e0", "e1"]
    assert out[0]["success"] and out[0]["steps"] == 5 and out[1] is BASE[1]


def test_a_rerun_that_decided_differently_before_the_base_end_is_refused():
    diverged = rec("e0", [L, F, F, S], "stopped", success=True)
    assert "actions differ at step 0" in same_until_base_end(BASE[0], diverged)
    with pytest.raises(ValueError, match="actions differ"):
        splice(BASE, [diverged], "exhausted")
    # an episode whose base did not end where the change acts cannot be re-run into it
    with pytest.raises(ValueError, match="ended in 'stopped'"):
        splice(BASE, [rec("e1", [F, F, F, S], "stopped", home=2)], "exhausted")
    with pytest.raises(ValueError, match="not in the base"):
        splice(BASE, [rec("zz", [S], "stopped")], "exhausted")


def test_main_writes_the_spliced_records_and_refuses_an_incomplete_rerun(tmp_path):
    def write(name, records):
        d = tmp_path / name
        d.mkdir()
        (d / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
        return str(d)

    base = write("base", BASE)
    empty = write("empty", [])
    assert main([base, empty, "--out", str(tmp_path / "none")]) == 2  # e0 ended exhausted and was not re-run
    assert missing_reruns(BASE, [], "exhausted") == ["e0"]
    rerun = write("rerun", [rec("e0", [F, L, F, S], "stopped", success=True)])
    out = tmp_path / "out"
    assert main([base, rerun, "--out", str(out)]) == 0
    lines = [json.loads(x) for x in (out / "episodes.jsonl").read_text().splitlines()]
    assert [r["success"] for r in lines] == [True, True]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["episodes"] == 2 and summary["sr"] == 1.0 and summary["spliced_from"]["rerun"] == rerun


R = "TURN_RIGHT"


def test_the_turn_in_place_guard_is_spliced_from_the_first_run_of_alternating_turns():
    from sim.evaluation.splice import ActsAt, first_oscillation

    acts_at = ActsAt(oscillation=4)
    looping = rec("e0", [F, L, R, L, L, R, L, R, L, R, L, R], "explore")  # the run of 4 ends at index 7
    assert first_oscillation(looping["trajectory"]["actions"], 4) == 7
    assert first_oscillation([2, 3, 2, 3], 4) == 3 and first_oscillation([2, 3, 1, 2, 3], 4) is None  # ints too
    base = [looping, BASE[1]]
    assert missing_reruns(base, [], acts_at) == ["e0"]  # e1 never turned to and fro: untouched
    fixed = rec("e0", [F, L, R, L, L, R, L, R, F, F, S], "stopped", success=True)  # differs from step 8 on
    out = splice(base, [fixed], acts_at)
    assert out[0] is fixed and out[1] is BASE[1]
    early = rec("e0", [F, L, R, L, L, R, L, F, F, S], "stopped", success=True)  # differs at step 7
    with pytest.raises(ValueError, match="actions differ at step 7"):
        splice(base, [early], acts_at)
    with pytest.raises(ValueError, match="never turned to and fro 4 times"):
        splice(base, [rec("e1", [F, F, F, S], "stopped", home=2)], acts_at)


def test_the_splice_and_the_agent_count_the_same_run():
    import random

    from agent.modes import MotionState
    from agent.motion import after_action
    from agent.types import Action
    from sim.evaluation.splice import first_oscillation

    rng = random.Random(3)
    for _ in range(200):
        actions = [
            rng.choice([Action.TURN_LEFT, Action.TURN_RIGHT, Action.TURN_RIGHT, Action.MOVE_FORWARD]) for _ in range(30)
        ]
        m, fired = MotionState(), None
        for k, a in enumerate(actions):  # the guard acts before action k + 1 when the run reached 5
            m = after_action(m, a)
            if m.alternating_turns >= 5:
                fired = k
                break
        assert first_oscillation([int(a) for a in actions], 5) == fired


def test_the_deadline_splices_the_episodes_that_went_past_its_first_step(tmp_path):
    from sim.evaluation.splice import ActsAt

    long_ = rec("long", [F, L, F, L, F, L], "explore")  # went on past step 3 (a time-out, say)
    short = rec("short", [F, F, S], "stopped", success=True, home=2)  # ended before step 3
    at = ActsAt(from_step=3)
    assert at.untouched(long_) == 3 and at.untouched(short) is None
    assert missing_reruns([long_, short], [], at) == ["long"]
    # the re-run may differ from step 3 on, not before
    out = splice([long_, short], [rec("long", [F, L, F, F, S], "stopped", success=True)], at)
    assert out[0]["success"] and out[0]["steps"] == 5 and out[1] is short
    with pytest.raises(ValueError, match="actions differ at step 2"):
        splice([long_, short], [rec("long", [F, L, L, F, S], "stopped")], at)
    with pytest.raises(ValueError, match="ended within its first 3 steps"):
        splice([long_, short], [rec("short", [F, F, F, S], "stopped", home=2)], at)
    # the command line: --from-step
    for name, records in (("base", [long_, short]), ("rerun", [rec("long", [F, L, F, F, S], "stopped", success=True)])):
        (tmp_path / name).mkdir()
        (tmp_path / name / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    assert (
        main([str(tmp_path / "base"), str(tmp_path / "rerun"), "--out", str(tmp_path / "out"), "--from-step", "3"]) == 0
    )
    got = [json.loads(x) for x in (tmp_path / "out" / "episodes.jsonl").read_text().splitlines()]
    assert [r["success"] for r in got] == [True, True]


def test_forgiving_splices_only_where_the_base_rejected_a_candidate(tmp_path, capsys):
    from sim.evaluation.splice import ActsAt

    gave_up = rec("g", [L, L, F, L, S], "exhausted")
    gave_up["modiin"].update(
        candidates=[{"id": 0, "state": "rejected"}], trace={"reid_score": [0.0, 0.0, 3.5, 60.0, 0.0]}
    )
    kept = rec("k", [F, F, S], "stopped", success=True, home=2)
    kept["modiin"].update(candidates=[{"id": 0, "state": "confirmed"}], trace={"reid_score": [80.0, 90.0, 95.0]})
    at = ActsAt(rejected=True)
    # no candidate before the first step with a score: the re-run must repeat the first 2 actions
    assert at.untouched(gave_up) == 2 and at.untouched(kept) is None
    out = splice([gave_up, kept], [rec("g", [L, L, F, F, S], "stopped", success=True)], at)
    assert out[0]["success"] and out[1] is kept
    with pytest.raises(ValueError, match="actions differ at step 1"):
        splice([gave_up, kept], [rec("g", [L, F, F, S], "stopped")], at)
    with pytest.raises(ValueError, match="rejected no candidate"):
        splice([gave_up, kept], [rec("k", [F, F, F, S], "stopped", home=2)], at)
    # --list names the episodes to re-run, for each kind of change
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in (gave_up, kept, *BASE)))
    assert main([str(tmp_path / "base"), "--list", "--rejected"]) == 0
    assert capsys.readouterr().out.split() == ["g"]
    assert main([str(tmp_path / "base"), "--list"]) == 0  # the last resort: the exhausted ones
    assert capsys.readouterr().out.split() == ["g", "e0"]
    with pytest.raises(SystemExit):
        main([str(tmp_path / "base"), "--rejected"])  # splicing needs RERUN and --out


def test_a_change_in_one_mode_splices_only_where_the_base_spent_a_step_in_it(tmp_path, capsys):
    from sim.evaluation.splice import ActsAt

    verified = rec("v", [L, L, F, L, S], "stopped")
    verified["modiin"].update(
        modes={"look_around": 2, "verify": 2, "stopped": 1}, trace={"reid_score": [0.0, 0.0, 0.0, 45.0, 0.0]}
    )
    direct = rec("d", [F, F, S], "stopped", success=True, home=2)
    direct["modiin"].update(modes={"approach": 2, "stopped": 1}, trace={"reid_score": [90.0, 90.0, 95.0]})
    at = ActsAt(in_mode="verify")
    assert at.untouched(verified) == 3 and at.untouched(direct) is None
    out = splice([verified, direct], [rec("v", [L, L, F, F, S], "stopped", success=True)], at)
    assert out[0]["success"] and out[1] is direct
    with pytest.raises(ValueError, match="actions differ at step 2"):
        splice([verified, direct], [rec("v", [L, L, L, F, S], "stopped")], at)
    with pytest.raises(ValueError, match="no step in mode 'verify'"):
        splice([verified, direct], [rec("d", [F, F, F, S], "stopped", home=2)], at)
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in (verified, direct)))
    assert main([str(tmp_path / "base"), "--list", "--in-mode", "verify"]) == 0
    assert capsys.readouterr().out.split() == ["v"]
    # at least N steps in the mode: 2 verify steps are enough for 2, not for 3
    assert ActsAt(in_mode="verify", in_mode_steps=2).untouched(verified) == 3
    assert ActsAt(in_mode="verify", in_mode_steps=3).untouched(verified) is None
    assert main([str(tmp_path / "base"), "--list", "--in-mode", "verify", "--in-mode-steps", "3"]) == 0
    assert capsys.readouterr().out.split() == []


def test_a_change_at_one_event_splices_only_where_the_base_had_a_step_with_it(tmp_path, capsys):
    from sim.evaluation.splice import ActsAt

    walled = rec("w", [L, L, F, L, S], "stopped")
    walled["modiin"].update(
        events={"look_around": 2, "goal_not_reachable_yet": 2, "stop_at_goal": 1},
        trace={"reid_score": [0.0, 0.0, 60.0, 45.0, 0.0]},
    )
    ring = rec("r", [L, F, S], "stopped", home=3)
    ring["modiin"].update(events={"verify_ring_not_reachable_yet": 1}, trace={"reid_score": [0.0, 30.0, 0.0]})
    direct = rec("d", [F, F, S], "stopped", success=True, home=2)
    direct["modiin"].update(events={"approach": 2, "stop_at_goal": 1}, trace={"reid_score": [90.0, 90.0, 95.0]})
    at = ActsAt(events=("goal_not_reachable_yet", "verify_ring_not_reachable_yet"))
    assert [at.untouched(r) for r in (walled, ring, direct)] == [2, 1, None]
    assert ActsAt(events=("goal_not_reachable_yet",)).untouched(ring) is None
    out = splice([walled, ring, direct], [rec("w", [L, L, F, F, S], "stopped", success=True)], at)
    assert out[0]["success"] and out[1] is ring and out[2] is direct
    with pytest.raises(ValueError, match="actions differ at step 1"):
        splice([walled, ring, direct], [rec("w", [L, F, F, S], "stopped")], at)
    with pytest.raises(ValueError, match="no step with event goal_not_reachable_yet or verify_ring"):
        splice([walled, ring, direct], [rec("d", [F, F, F, S], "stopped", home=2)], at)
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in (walled, ring, direct)))
    # a search event (a rescan) can come before any score: only the episode is checked then
    rescanned = rec("s", [L, L, S], "exhausted", home=4)
    rescanned["modiin"].update(events={"rescan": 1}, trace={"reid_score": [0.0, 0.0, 0.0]})
    with_rescan = ActsAt(events=("goal_not_reachable_yet", "rescan"))
    assert [with_rescan.untouched(r) for r in (walled, rescanned, direct)] == [2, 0, None]
    assert ActsAt(events=("rescan:2",)).untouched(rescanned) is None  # EVENT:N: at least N steps
    assert ActsAt(events=("rescan:1",)).untouched(rescanned) == 0
    out = splice([walled, rescanned], [rec("s", [F, S], "stopped", success=True, home=4)], with_rescan)
    assert out[1]["success"] and out[0] is walled
    argv = [str(tmp_path / "base"), "--list", "--event", "goal_not_reachable_yet"]
    assert main([*argv, "--event", "verify_ring_not_reachable_yet"]) == 0
    assert capsys.readouterr().out.split() == ["w", "r"]
    assert main(argv) == 0
    assert capsys.readouterr().out.split() == ["w"]


def test_a_change_after_a_failed_move_splices_only_where_the_base_had_one(tmp_path, capsys):
    from sim.evaluation.splice import ActsAt

    # "b": its third action, a forward move, did not move the robot (estimate and truth); "c"
    # moved on every forward move; both approached a candidate first scored at step 1
    bumped = rec("b", [L, F, F, F, S], "stopped", success=True)
    poses = bumped["trajectory"]["poses_world"]
    poses[3:] = [[0.25, 0.0, 0.0], [0.25, 0.0, 0.0], [0.5, 0.0, 0.0]]
    bumped["trajectory"]["poses_estimate_world"] = [[x + 0.01, y, t] for x, y, t in poses]
    clear = rec("c", [L, F, F, S], "stopped", success=True, home=2)
    for r in (bumped, clear):
        r["modiin"].update(
            events={"approach": 3, "stop_at_goal": 1}, trace={"reid_score": [0.0, 50.0, 60.0, 70.0, 0.0]}
        )
    at = ActsAt(events=("approach", "verify_approach"), collided=True)
    # it cannot act before the step after the failed move (index 2)
    assert [at.untouched(r) for r in (bumped, clear)] == [3, None]
    assert ActsAt(events=("approach",)).untouched(clear) == 1
    assert "after a failed forward move" in at.why_not(clear)
    again = json.loads(json.dumps(bumped))
    again["trajectory"]["actions"][3] = L
    again["trajectory"]["poses_world"][4] = [0.25, 0.0, 0.5]
    out = splice([bumped, clear], [again], at)
    assert out[1] is clear and out[0]["trajectory"]["actions"][3] == L
    again["trajectory"]["actions"][2] = L  # differs before the failed move: not this change
    with pytest.raises(ValueError, match="actions differ at step 2"):
        splice([bumped, clear], [again], at)
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in (bumped, clear)))
    assert main([str(tmp_path / "base"), "--list", "--event", "approach", "--collided"]) == 0
    assert capsys.readouterr().out.split() == ["b"]
    with pytest.raises(SystemExit):
        main([str(tmp_path / "base"), "--list", "--collided"])
