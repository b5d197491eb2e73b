"""Replay of a run, step by step: the timeline (one entry per step, in words), marks to
jump to, and per step the camera thumbnail, the map as the agent knew it and the goal
candidates (``console.replay``)."""

from __future__ import annotations

import io
from typing import Any

from fastapi import APIRouter, Path
from fastapi.responses import Response
from PIL import Image
from starlette.concurrency import run_in_threadpool

from console.deps import ConsoleDep, TokenDep, error
from console.jsonio import json_safe
from console.replay import map_picture, replay_marks
from console.routes.runs import get_row
from console.words import action_words, doing_words, mode_words, step_detail, step_words

router = APIRouter(tags=["replay"])

StepParam = Path(ge=0, le=100_000, description="the step number (0 = the first action)")


def _timeline(console: Any, run_id: str) -> tuple[list[dict[str, Any]], dict[int, dict[str, Any]]]:
    return console.store.steps_json(run_id), console.store.replay_extras(run_id)


@router.get("/api/runs/{run_id}/replay", summary="A run's timeline for replay: every step in words, marks to jump to")
def replay_index(run_id: str, console: ConsoleDep) -> dict[str, Any]:
    row = get_row(console, run_id)
    steps, extras = _timeline(console, run_id)
    timeline = []
    for s in steps:
        cands = extras.get(s["step"], {}).get("candidates", [])
        timeline.append(
            {
                # every field of the one step schema (console.step_schema) but the per-part timings,
                # kept out so that a 1000-step timeline stays small; "action" is the name here
                **{k: v for k, v in s.items() if k != "timings"},
                "action": s["action_name"],
                "action_words": action_words(s["action_name"]),
                "mode_words": mode_words(s["mode"]),
                "words": step_words(s),
                "detail": step_detail(s),
                "pose": [s["x_m"], s["y_m"], s["yaw_rad"]],
                "n_candidates": len([c for c in cands if c.get("state") != "rejected"]),
                "has_frame": s["step"] in extras,
            }
        )
    return json_safe(
        {
            "run_id": run_id,
            "status": row["status"],
            "n_steps": len(steps),
            "steps": timeline,
            "map_steps": console.store.replay_map_steps(run_id),
            "marks": replay_marks(steps, extras),
        }
    )


@router.get(
    "/api/runs/{run_id}/replay/latest", summary="The latest recorded step of a run (live view of an active run)"
)
def replay_latest(run_id: str, console: ConsoleDep) -> dict[str, Any]:
    get_row(console, run_id)
    step = console.store.replay_latest_step(run_id)
    if step is None:
        raise error(404, "no_steps", f"run {run_id} has no recorded step yet")
    return replay_step(run_id, console, step)


@router.get("/api/runs/{run_id}/replay/{step}", summary="One step of a run: what the agent saw, did and had in mind")
def replay_step(run_id: str, console: ConsoleDep, step: int = StepParam) -> dict[str, Any]:
    get_row(console, run_id)
    steps, extras = _timeline(console, run_id)
    me = next((s for s in steps if s["step"] == step), None)
    if me is None:
        raise error(404, "unknown_step", f"run {run_id} has no step {step}")
    ex = extras.get(step, {})
    return json_safe(
        {
            **me,
            "words": step_words(me),
            "doing": doing_words(me),
            "detail": step_detail(me),
            "mode_words": mode_words(me["mode"]),
            "candidates": ex.get("candidates", []),
            "target": ex.get("target"),
            "target_kind": ex.get("target_kind"),
            "explored_m2": ex.get("explored_m2"),
            "n_goal_points": me["n_goal_points"],
            "frame_url": f"/api/runs/{run_id}/replay/{step}/frame.jpg" if step in extras else None,
            "map_url": f"/api/runs/{run_id}/replay/{step}/map.png",
        }
    )


@router.get("/api/runs/{run_id}/replay/{step}/frame.jpg", summary="The camera thumbnail of a step")
def replay_frame(run_id: str, console: ConsoleDep, step: int = StepParam) -> Response:
    get_row(console, run_id)
    jpeg = console.store.replay_frame(run_id, step)
    if jpeg is None:
        raise error(404, "no_frame", f"no picture was kept for step {step} of run {run_id}")
    return Response(jpeg, media_type="image/jpeg", headers={"cache-control": "max-age=86400"})


@router.get("/api/runs/{run_id}/replay/{step}/map.png", summary="The map as the agent knew it at a step")
async def replay_map(run_id: str, console: ConsoleDep, step: int = StepParam) -> Response:
    get_row(console, run_id)
    steps, extras = _timeline(console, run_id)
    if not any(s["step"] == step for s in steps):
        raise error(404, "unknown_step", f"run {run_id} has no step {step}")
    rgb = await run_in_threadpool(map_picture, console.store, run_id, step, steps, extras.get(step, {}))
    if rgb is None:
        raise error(404, "unknown_step", f"run {run_id} has no step {step}")
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG", compress_level=3)
    return Response(buf.getvalue(), media_type="image/png", headers={"cache-control": "max-age=86400"})


@router.post(
    "/api/runs/{run_id}/replay/{step}/show",
    summary="Show a step of a finished run in the 3D viewer",
    dependencies=[TokenDep],
)
def replay_show(run_id: str, console: ConsoleDep, step: int = StepParam) -> dict[str, Any]:
    row = get_row(console, run_id)
    if console.viewer is None:
        raise error(404, "no_viewer", "this console runs without the 3D viewer")
    if console.manager.active_run_id is not None:
        raise error(409, "run_active", "the viewer is showing the active run; replay after it ends")
    steps, extras = _timeline(console, run_id)
    if not any(s["step"] == step for s in steps):
        raise error(404, "unknown_step", f"run {run_id} has no step {step}")
    console.viewer.show_replay(console.store, row, steps, extras, step)
    return {"run_id": run_id, "step": step}
