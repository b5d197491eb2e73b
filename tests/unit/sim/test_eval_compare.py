import json

import pytest

from sim.evaluation.compare import compare, load_records, main, paired_difference


def rec(eid, home, success, spl=None, cause=None, variant="v"):
    return {
        "episode_id": eid,
        "scene_seed": home,
        "success": success,
        "spl": (0.5 if success else 0.0) if spl is None else spl,
        "ne": 0.1 if success else 3.0,
        "max_steps_reached": False,
        "category": "chair",
        "failure_cause": None if success else cause,
        "variant": variant,
    }


def write(tmp_path, name, records):
    d = tmp_path / name
    d.mkdir()
    (d / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return str(d)


BASE = [
    rec("a0", 1, True),
    rec("a1", 1, False, cause="reid_false_negative"),
    rec("b0", 2, False, cause="local_navigation"),
    rec("b1", 2, True),
]


def test_paired_difference_counts_wins_and_losses_on_the_same_episodes(tmp_path):
    base = load_records(write(tmp_path, "base", BASE))
    var = load_records(
        write(
            tmp_path,
            "var",
            [
                rec("a0", 1, True),
                rec("a1", 1, True),
                rec("b0", 2, True),
                rec("b1", 2, False, cause="exploration"),
                rec("c0", 3, True),
            ],
        )
    )
    p = paired_difference(base, var)
    assert p.episodes == 4 and p.homes == 2  # c0 is not in the base: not compared
    assert (p.won, p.lost) == (2, 1)
    assert p.d_sr == pytest.approx(0.25)
    assert p.d_sr_ci95[0] <= 0.25 <= p.d_sr_ci95[1] and p.d_sr_ci95[0] < p.d_sr_ci95[1]
    same = paired_difference(base, base)
    assert same.d_sr == 0.0 and same.d_sr_ci95 == (0.0, 0.0) and (same.won, same.lost) == (0, 0)


def test_compare_tables_use_only_the_common_episodes(tmp_path):
    b = write(tmp_path, "base", BASE)
    v = write(tmp_path, "var", [rec("a0", 1, True, variant="w"), rec("a1", 1, True, variant="w")])
    text = compare([b, v])
    assert "Episodes in common: 2 (1 homes)" in text
    rows = [line for line in text.splitlines() if line.startswith("| ")]
    # base on the common episodes a0, a1: SR 0.5; the variant: 1.0, +0.5 paired, one won
    assert any(f"{b} (v)" in r and "| 0.500 [" in r for r in rows)
    assert any(f"{v} (w)" in r and "| 1.000 [" in r for r in rows)
    assert any(f"{v} (w)" in r and "+0.500" in r and r.rstrip().endswith("| 1 | 0 | 0 of 2 |") for r in rows)
    # failure counts on the common episodes: the base lost a1 to re-ID
    assert any(f"{b} (v)" in r and r.startswith(f"| {b} (v) | 1 | 1 | 0 |") for r in rows)


def test_same_actions_and_cost_against_the_first_run(tmp_path):
    def timed(eid, home, actions, wall_s, agent_ms):
        return {
            **rec(eid, home, True),
            "trajectory": {"actions": actions},
            "timing": {"wall_s": wall_s, "agent_ms_per_step": agent_ms, "sim_ms_per_step": 50.0},
        }

    b = write(tmp_path, "base", [timed("a0", 1, [1, 2, 0], 100.0, 90.0), timed("b0", 2, [3, 0], 200.0, 110.0)])
    v = write(
        tmp_path,
        "var",
        [timed("a0", 1, [1, 2, 0], 50.0, 40.0), timed("b0", 2, [3, 1, 0], 100.0, 60.0)],
    )
    rows = [line for line in compare([b, v]).splitlines() if line.startswith("| ")]
    assert any(r.startswith(f"| {v} (v) |") and r.rstrip().endswith("| 0 | 0 | 1 of 2 |") for r in rows)
    # base: 2 episodes in 300 s = 24 per hour, agent median 100 ms; variant: 48 per hour, twice the rate
    assert f"| {b} (v) | 100 | 50 | 24.0 | 1.00 |" in rows
    assert f"| {v} (v) | 50 | 50 | 48.0 | 2.00 |" in rows


def test_bad_inputs_are_clear_errors(tmp_path, capsys):
    b = write(tmp_path, "base", BASE)
    other = write(tmp_path, "other", [rec("z0", 9, True)])
    with pytest.raises(ValueError, match="no episode in common"):
        compare([b, other])
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "episodes.jsonl").write_text('{"episode_id": "a0"}\nnot json\n')
    with pytest.raises(ValueError, match="not JSON"):
        load_records(broken)
    assert main([b, str(tmp_path / "missing")]) == 2
    assert "no episodes.jsonl" in capsys.readouterr().err


def test_identical_lists_every_difference_but_timings(tmp_path):
    import json

    from sim.evaluation.compare import identical, main

    base = {
        "episode_id": "e1",
        "success": True,
        "timing": {"wall_s": 1.0},
        "modiin": {"final_reason": "a", "median_ms": {"total": 3.0}, "trace": {"s": [1, 2]}},
        "agent_config": {"policy": {"verify": False}},
    }
    same = json.loads(json.dumps(base))
    same["timing"]["wall_s"] = 9.0  # timings never count
    same["modiin"]["median_ms"]["total"] = 4.0
    moved = json.loads(json.dumps(base))
    moved["modiin"]["trace"]["s"][1] = 3
    moved["agent_config"] = {"policy": {}}
    for name, rec in (("a", base), ("b", same), ("c", moved)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "episodes.jsonl").write_text(json.dumps(rec) + "\n")
    assert identical(str(tmp_path / "a"), str(tmp_path / "b")) == (1, [])
    n, lines = identical(str(tmp_path / "a"), str(tmp_path / "c"))
    assert n == 1 and lines == [
        "e1: agent_config.policy.verify (only in the first): false -> null",
        "e1: modiin.trace.s[1]: 2 -> 3",
    ]
    assert identical(str(tmp_path / "a"), str(tmp_path / "c"), ["agent_config"])[1] == ["e1: modiin.trace.s[1]: 2 -> 3"]
    assert main([str(tmp_path / "a"), str(tmp_path / "b"), "--identical"]) == 0
    assert main([str(tmp_path / "a"), str(tmp_path / "c"), "--identical"]) == 1


def test_identical_leaves_out_the_timings_of_a_sequences_subtasks() -> None:
    from sim.evaluation.compare import TIMING_FIELDS, record_differences

    def seq(wall_s: float, steps: int) -> dict:
        sub = {"steps": steps, "timing": {"wall_s": wall_s, "cpu_s": wall_s}, "modiin": {"median_ms": {"t": wall_s}}}
        return {"episode_id": "q", "timing": {"wall_s": wall_s}, "subtasks": [sub, dict(sub)]}

    assert record_differences(seq(1.0, 3), seq(2.0, 3), TIMING_FIELDS) == []
    assert record_differences(seq(1.0, 3), seq(2.0, 4), TIMING_FIELDS) == ["subtasks[0].steps", "subtasks[1].steps"]


def seq(sid, home, subtasks):
    """A multi-goal record: (success, spl) per goal."""
    subs = []
    for g, (ok, spl) in enumerate(subtasks):
        s = rec(f"{sid}-g{g}", home, ok, spl=spl, cause="exploration")
        del s["episode_id"], s["scene_seed"], s["variant"]
        subs.append({**s, "goal_index": g, "kind": "new"})
    return {"episode_id": sid, "scene_seed": home, "variant": "v", "goals": len(subs), "subtasks": subs}


def test_multi_goal_runs_are_compared_subtask_by_subtask_first_goal_against_later(tmp_path):
    base = write(
        tmp_path,
        "nomem",
        [seq("s1", 1, [(True, 0.8), (True, 0.2), (False, 0.0)]), seq("s2", 2, [(True, 0.6), (True, 0.4), (True, 0.4)])],
    )
    mem = write(
        tmp_path,
        "mem",
        [seq("s1", 1, [(True, 0.8), (True, 0.6), (True, 0.5)]), seq("s2", 2, [(True, 0.6), (True, 0.8), (False, 0.0)])],
    )
    out = compare([base, mem])
    assert out.startswith("Episodes in common: 6 (2 homes)")  # the subtasks are the episodes
    # first goals the same; later: SR 3/4 both, SPL 0.25 -> 0.475, ratio 1.9 (sums 1.0 -> 1.9)
    row = out.splitlines()[-1]  # the last table: paired, first against later goals
    assert row.startswith(f"| {mem}")
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1].startswith("+0.000") and cells[2].startswith("+0.000")
    assert cells[3].startswith("+0.000") and cells[4].startswith("+0.225")
    assert cells[5].startswith("1.90 [")
    later = next(line for line in out.splitlines() if line.startswith(f"| {base}") and "0.250 [" in line)
    assert "| 0.750 [" in later
    with pytest.raises(ValueError, match="multi-goal and single-goal"):
        compare([base, write(tmp_path, "single", BASE)])


def test_runs_of_turns_to_and_fro_stands_and_the_stuck_table(tmp_path):
    from sim.evaluation.compare import STAND_STEPS, STUCK_TURNS, longest_stand, to_and_fro_runs

    L, R, F = 2, 3, 1
    # two turns the same way start a new run; a forward move ends one; runs of one turn are no runs
    assert to_and_fro_runs([L, R, L, L, R, F, R, L]) == [3, 2, 2]
    assert to_and_fro_runs([L, L, L, F, R]) == []
    # within 0.5 m: two forward moves of 0.25 m from a place still count, a third does not
    assert longest_stand([[0, 0, 0], [0, 0, 1], [0.25, 0, 1], [0.5, 0, 1], [0.75, 0, 1]]) == 3

    def walked(eid, home, actions, out_of_steps=False):
        # forward moves go 0.25 m along x, turns stay: the poses the actions lead to
        poses, x = [[0.0, 0.0, 0.0]], 0.0
        for a in actions:
            x += 0.25 if a == F else 0.0
            poses.append([x, 0.0, 0.0])
        traj = {"actions": actions, "poses_world": poses}
        return {**rec(eid, home, not out_of_steps), "trajectory": traj, "max_steps_reached": out_of_steps}

    stuck = [F] + [L, R] * 60 + [F] + [R, L] * 6  # runs of 120 and 12 turns, 134 steps within 0.5 m
    b = write(tmp_path, "base", [walked("a0", 1, stuck, True), walked("b0", 2, [L, R, L, F, 0])])
    v = write(tmp_path, "var", [walked("a0", 1, [F, L, F, 0]), walked("b0", 2, [L, R, L, F, 0])])
    rows = [line for line in compare([b, v]).splitlines() if line.startswith("| ")]
    assert STUCK_TURNS <= 12 and STAND_STEPS <= 133
    assert f"| {b} (v) | 1 | 1 | 134 | 1 | 132 | 120 |" in rows
    assert f"| {v} (v) | 0 | 0 | 5 | 0 | 0 | 3 |" in rows  # b0: a turn run of 3, 5 steps within 0.5 m


def test_outcomes_lists_each_episode_some_run_failed_with_its_cause_in_every_run(tmp_path):
    base = write(tmp_path, "base", BASE)
    var = write(
        tmp_path,
        "var",
        [
            rec("a0", 1, False, cause="exploration"),
            rec("a1", 1, True),
            rec("b0", 2, False, cause="mapping_ghosts"),
            rec("b1", 2, True),
        ],
    )
    text = compare([base, var], outcomes=True)
    rows = [line for line in text.splitlines() if line.startswith("| a") or line.startswith("| b")]
    assert rows == [
        "| a0 | - | exploration | 1 of 2 |",
        "| a1 | reid_false_negative | - | 1 of 2 |",
        "| b0 | local_navigation | mapping_ghosts | 2 of 2 |",
    ]  # b1 succeeded in both: not listed
    assert "Episodes some run failed (3 of 4" in text
    assert "Episodes some run failed" not in compare([base, var])
