"""``imgnav eval --memory`` with the real Mod-IIN agent on a real generated sequence (issue 31):
new goal, new goal, the first goal again (a repeat, photographed from elsewhere), 20 steps each.
The second goal's agent starts with the first goal's keyframes; the repeat is found in memory
before its first step and reached without looking around or exploring; the subtasks share one
frame, the first start's; a resumed run without ``--memory`` is refused."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

from agent.types import Pose2D
from console.cli import main
from sim.sequence_gen import SequenceGenConfig, generate_sequence_set


@pytest.fixture(scope="module")
def repeat_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One val sequence (seed 0, a 6-room home): a toilet, a potted plant, the toilet again."""
    out = tmp_path_factory.mktemp("repeat-sequence")
    cfg = SequenceGenConfig(goals=3, sequences_per_scene=1, repeat_share=1.0)
    (seq,) = generate_sequence_set("val", 0, 1, out, cfg, progress=False)
    assert [g.kind for g in seq.goals] == ["new", "new", "repeat"] and seq.goals[2].of_goal == 0
    return out


def test_a_repeated_goal_is_found_in_memory_and_reached_without_exploring(
    repeat_sequence: Path, tmp_path: Path
) -> None:
    out = tmp_path / "mem"
    argv = ["eval", "--episodes", str(repeat_sequence), "--agent", "modiin", "--out", str(out)]
    argv += ["--subtask-budget", "20", "--modiin-threads", "1"]
    assert main([*argv, "--memory"]) == 0
    lines = (out / "episodes.jsonl").read_text().splitlines()
    (rec,) = [json.loads(x) for x in lines]
    assert rec["memory"] is True and rec["error"] is None
    first, second, repeat = subs = rec["subtasks"]
    mem = [s["memory"] for s in subs]
    # the first goal begins from nothing; the second with what the first one's search kept
    assert mem[0]["keyframes_at_start"] == 0 and mem[0]["first_mode"] == "look_around"
    assert mem[0]["keyframes"] > 0 and mem[1]["keyframes_at_start"] == mem[0]["keyframes"]
    assert mem[1]["recall_ms"] > 0 and mem[2]["keyframes_at_start"] >= mem[1]["keyframes_at_start"]
    # the repeat: a candidate from remembered views before its first step, no look-around, no
    # exploring, reached
    assert repeat["kind"] == "repeat" and mem[2]["recall_candidate"] and mem[2]["recalled_views"] >= 1
    assert mem[2]["look_around_skipped"] and mem[2]["first_mode"] in ("approach", "verify")
    assert not {"look_around", "explore", "rescan"} & set(repeat["modiin"]["modes"]), repeat["modiin"]["modes"]
    assert repeat["success"] and repeat["stop_reason"] == "stop", repeat
    # one frame: subtask k's origin is its start in the first start's frame (clean: belief = truth)
    start0 = Pose2D(*first["start_pose_world"])
    for s in subs:
        truth = Pose2D(*s["start_pose_world"]).relative_to(start0)
        x, y, yaw = s["memory"]["frame_origin"]
        assert math.hypot(x - truth.x_m, y - truth.y_m) < 1e-3
        assert abs(math.remainder(yaw - truth.yaw_rad, math.tau)) < 1e-3
    # the attribution read the remembered candidate in that frame: on the goal
    assert repeat["modiin"]["candidate_to_goal_m"] is not None and repeat["modiin"]["candidate_to_goal_m"] <= 1.0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["memory"] is True and summary["memory_use"]["later_goals"] == 2
    assert summary["memory_use"]["look_around_skipped_share"] >= 0.5
    assert summary["first_goal"]["episodes"] == 1 and summary["later_goals"]["episodes"] == 2
    # a resumed run without --memory is refused, the records untouched
    assert main(argv) == 2
    assert (out / "episodes.jsonl").read_text().splitlines() == lines


def test_the_step_trace_of_a_later_goal_runs_the_goals_before_it(
    repeat_sequence: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # benchmarks/trace_steps.py on SEQUENCE-g2: the two goals before it run first and share the
    # memory, so the repeat's first printed steps are already about the remembered candidate
    import benchmarks.trace_steps as trace

    argv = ["--episodes", str(repeat_sequence), "--agent", "modiin", "--out", str(tmp_path / "x")]
    argv += ["--subtask-budget", "20", "--modiin-threads", "1", "--memory"]
    (seq_id,) = [d["episode_id"] for d in json.loads((repeat_sequence / "episodes.json").read_text())["episodes"]]
    old = sys.argv
    sys.argv = ["trace_steps.py", *argv, "--", f"{seq_id}-g2", 0, 6]
    sys.argv = [str(a) for a in sys.argv]
    try:
        assert trace.main() == 0
    finally:
        sys.argv = old
    lines = [x for x in capsys.readouterr().out.splitlines() if x[:4].strip().isdigit()]
    assert [int(x.split()[0]) for x in lines] == list(range(6))
    modes = {x[40:51].strip() for x in lines}  # the columns of Printer.step
    assert modes and modes <= {"approach", "verify", "stopped"}, lines
