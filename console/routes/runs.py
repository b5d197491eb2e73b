"""Runs: start (multipart photo + options), list, details, stop, live status, artifacts;
and the console-wide configuration and backend descriptions."""

from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, File, Form, Query, Request, UploadFile
from fastapi.responses import FileResponse, JSONResponse, StreamingResponse
from starlette.concurrency import run_in_threadpool

from console.artifacts import ARTIFACT_NAMES, existing_artifacts, run_dir, valid_run_id
from console.context import Console
from console.deps import ConsoleDep, TokenDep, check_token, error
from console.jsonio import json_safe
from console.manager import RunConflict
from console.options import RunForm
from console.photos import PhotoError, decode_photo
from console.routes.memory import check_goal_from_run, goal_from_run_photo
from console.session import OptionsError, ProviderUnavailable
from console.words import distance_driven_m, run_summary, timing_rows

router = APIRouter(tags=["runs"])

FINAL = ("finished", "stopped", "failed", "interrupted")
SSE_HEADERS = {"cache-control": "no-cache", "x-accel-buffering": "no"}


def run_view(console: Console, row: dict[str, Any], steps: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    """A run as the API shows it: the stored row, whether it is active, its artifacts' URLs,
    and its outcome in words (``summary``) with the timings as labelled values."""
    out = dict(row)
    out["active"] = console.manager.active_run_id == row["id"]
    out["artifacts"] = {
        name: f"/api/runs/{row['id']}/artifacts/{name}" for name in existing_artifacts(console.data_dir, row["id"])
    }
    driven = distance_driven_m(steps) if steps is not None else None
    out["summary"] = run_summary(row, driven)
    out["timings_words"] = timing_rows(row.get("timings") or {})
    return json_safe(out)


def get_row(console: Console, run_id: str) -> dict[str, Any]:
    row = console.store.get_run(run_id) if valid_run_id(run_id) else None
    if row is None:
        raise error(404, "unknown_run", f"no run {run_id!r}")
    return row


@router.get("/api/config", summary="Backends, viewer and limits")
def get_config(console: ConsoleDep) -> dict[str, Any]:
    backends = []
    for name, provider in console.providers.items():
        ok, why = provider.available()
        backends.append({"name": name, "label": provider.label, "available": ok, "why": why})
    viewer = console.viewer
    return {
        "backends": backends,
        "default_backend": next(iter(console.providers), None),
        "viewer": {"port": viewer.port} if viewer is not None else None,
        "token_required": console.token is not None,
        "active_run": console.manager.active_run_id,
        "limits": {
            "max_photo_bytes": console.config.photo_limits.max_bytes,
            "max_photo_pixels": console.config.photo_limits.max_pixels,
            "max_request_bytes": console.config.max_request_bytes,
        },
    }


@router.get("/api/backends/{name}", summary="What a backend offers (homes, starts, gallery)")
def describe_backend(name: str, console: ConsoleDep) -> dict[str, Any]:
    provider = console.providers.get(name)
    if provider is None:
        raise error(404, "unknown_backend", f"no backend {name!r}; choose one of {sorted(console.providers)}")
    ok, why = provider.available()
    return json_safe({"name": name, "label": provider.label, "available": ok, "why": why, **provider.describe()})


@router.post("/api/runs", status_code=201, summary="Start a run with a goal photo (or an earlier run's)")
async def start_run(
    request: Request,
    console: ConsoleDep,
    goal_image: Annotated[
        UploadFile | None, File(description="the goal photo: JPEG, PNG, WebP or HEIC (required without goal_from_run)")
    ] = None,
    backend: Annotated[str | None, Form(description="backend name (default: the simulator)")] = None,
    home: Annotated[str | None, Form(description="simulator home id (default: the first)")] = None,
    start: Annotated[
        str | None, Form(description="simulator start: a start id, 'x,y,yaw_deg' in the home frame, or 'random'")
    ] = None,
    episode: Annotated[str | None, Form(description="simulator episode id (sets home, start and target)")] = None,
    gallery_item: Annotated[
        str | None, Form(description="the gallery image the photo was chosen from (makes the target known)")
    ] = None,
    target_instance: Annotated[str | None, Form(description="the target instance id, if known")] = None,
    max_steps: Annotated[int | None, Form(description="step budget (default and maximum: 1000)")] = None,
    memory: Annotated[
        str | None,
        Form(
            description="simulator and Stretch: 'on' (default) starts from what the robot remembers of the home "
            "and adds to it; 'off' starts from nothing and leaves the home's memory as it was"
        ),
    ] = None,
    goal_from_run: Annotated[
        str | None,
        Form(
            description="instead of a photo, the goal photo of an earlier run whose request the home's memory "
            "remembers (asking for a known object again, from memory); only in that run's home (a simulator "
            "home, or the robot's)"
        ),
    ] = None,
    token: Annotated[str | None, Form(description="the console token when it is required")] = None,
) -> JSONResponse:
    received_s = time.time()
    check_token(console, request, token)
    name = backend or next(iter(console.providers), "")
    provider = console.providers.get(name)
    if provider is None:
        raise error(422, "unknown_backend", f"no backend {name!r}; choose one of {sorted(console.providers)}")
    ok, why = provider.available()
    if not ok:
        raise error(503, "backend_unavailable", f"the {provider.label} cannot be used now: {why}")
    active = console.manager.active_run_id
    if active is not None:  # answer before reading the photo; start() checks again under its lock
        raise error(409, "run_active", f"run {active} is active; stop it or wait for it to end")
    form = RunForm.of(
        home=home,
        start=start,
        episode=episode,
        gallery_item=gallery_item,
        target_instance=target_instance,
        max_steps=max_steps,
        memory=memory,
    )
    source = None  # goal_from_run: the stored run whose goal photo this run is given
    if goal_from_run:
        source, data = await run_in_threadpool(
            goal_from_run_photo, console, provider, goal_from_run, form, goal_image is not None
        )
    elif goal_image is None:
        raise error(422, "no_goal_image", "send the goal photo (goal_image), or goal_from_run")
    else:
        data = await goal_image.read(console.config.photo_limits.max_bytes + 1)
    t0 = time.perf_counter()
    try:
        photo = await run_in_threadpool(decode_photo, data, console.config.photo_limits)
    except PhotoError as exc:
        raise error(exc.status, exc.code, str(exc)) from None
    t1 = time.perf_counter()
    try:
        # in a thread: checking a custom start builds the home's geometry once (~0.5 s)
        resolved = await run_in_threadpool(provider.resolve, form, photo.dhash, photo.sha256)
    except OptionsError as exc:
        raise error(422, "bad_options", str(exc)) from None
    except ProviderUnavailable as exc:
        raise error(503, "backend_unavailable", str(exc)) from None
    if source is not None:  # in a thread: the first look at the home's memory reads its file
        await run_in_threadpool(check_goal_from_run, provider, resolved, source)
    request_timings = {"decode_s": t1 - t0, "resolve_s": time.perf_counter() - t1}  # the run's timings keep them
    try:
        run_id = console.manager.start(
            resolved, photo, data, received_s, request_timings, None if source is None else source["id"]
        )
    except RunConflict as exc:
        raise error(409, "run_active", str(exc)) from None
    except RuntimeError as exc:
        raise error(503, "shutting_down", str(exc)) from None
    return JSONResponse(
        run_view(console, get_row(console, run_id)), status_code=201, headers={"location": f"/api/runs/{run_id}"}
    )


@router.get("/api/runs", summary="Recent runs, newest first (filter by outcome, status, home, backend)")
def list_runs(
    console: ConsoleDep,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
    outcome: Annotated[str | None, Query(max_length=40)] = None,
    status: Annotated[str | None, Query(max_length=40)] = None,
    backend: Annotated[str | None, Query(max_length=40)] = None,
    home: Annotated[str | None, Query(max_length=80)] = None,
) -> dict[str, Any]:
    rows = console.store.list_runs(limit, offset, outcome=outcome, status=status, backend=backend, home=home)
    return {"runs": [run_view(console, r) for r in rows], "active_run": console.manager.active_run_id}


@router.get("/api/runs/{run_id}", summary="One run (and its steps with ?steps=true)")
def get_run(run_id: str, console: ConsoleDep, steps: bool = False) -> dict[str, Any]:
    row = get_row(console, run_id)
    step_rows = console.store.steps_json(run_id) if steps or row["status"] in FINAL else None
    out = run_view(console, row, step_rows)
    if steps:
        out["steps"] = json_safe(step_rows)
    return out


@router.post("/api/runs/{run_id}/stop", summary="Stop a run after its current step", dependencies=[TokenDep])
def stop_run(run_id: str, console: ConsoleDep) -> dict[str, Any]:
    row = get_row(console, run_id)
    stopping = console.manager.stop(run_id)
    if not stopping and row["status"] not in FINAL:
        # Created but its worker already ended between the two reads: report what is stored.
        row = get_row(console, run_id)
    return {"run_id": run_id, "stopping": stopping, "status": "stopping" if stopping else row["status"]}


@router.get("/api/runs/{run_id}/events", summary="Live status of one run (server-sent events)")
async def run_events(run_id: str, console: ConsoleDep) -> StreamingResponse:
    get_row(console, run_id)
    return StreamingResponse(console.hub.subscribe(run_id), media_type="text/event-stream", headers=SSE_HEADERS)


@router.get("/api/events", summary="Live status of all runs and console log lines (server-sent events)")
async def all_events(console: ConsoleDep) -> StreamingResponse:
    return StreamingResponse(console.hub.subscribe(None), media_type="text/event-stream", headers=SSE_HEADERS)


@router.get("/api/runs/{run_id}/artifacts/{name}", summary="A run's file: goal photo, trajectory, map, video")
def artifact(run_id: str, name: str, console: ConsoleDep) -> FileResponse:
    get_row(console, run_id)
    if name not in ARTIFACT_NAMES:
        raise error(404, "unknown_artifact", f"no artifact {name!r}; artifacts are {sorted(ARTIFACT_NAMES)}")
    path = run_dir(console.data_dir, run_id) / name
    if not path.is_file():
        raise error(404, "not_written", f"{name} has not been written for run {run_id}")
    return FileResponse(path, media_type=ARTIFACT_NAMES[name])
