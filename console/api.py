"""The console's HTTP API and pages (FastAPI). OpenAPI docs at /docs.

    GET  /                         landing: phone page on small screens, console page otherwise
    GET  /phone, /console          the pages (static/)
    GET  /api/config               backends and whether they are usable, viewer port, limits
    GET  /api/backends/{name}      what a backend offers (simulator: homes, starts, gallery)
    GET  /api/sim/gallery/{home}/{file}   a gallery goal image
    POST /api/runs                 start a run (multipart: goal_image + options)    -> 201, 409 if busy
    GET  /api/runs                 recent runs
    GET  /api/runs/{id}            one run (with its steps if ?steps=true)
    POST /api/runs/{id}/stop       stop a run after its current step
    GET  /api/runs/{id}/events     live status stream (server-sent events)
    GET  /api/events               all runs' status events and console log lines (SSE)
    GET  /api/runs/{id}/artifacts/{name}   goal photo, trajectory JSON, map PNG, run video
"""

from __future__ import annotations

import logging
import time
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated, Any, AsyncIterator

from fastapi import FastAPI, File, Form, HTTPException, Query, Request, UploadFile
from fastapi.responses import FileResponse, JSONResponse, RedirectResponse, StreamingResponse
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.middleware.trustedhost import TrustedHostMiddleware

from console.artifacts import ARTIFACT_NAMES, existing_artifacts, run_dir, valid_run_id
from console.context import Console
from console.manager import RunConflict
from console.photos import PhotoError, decode_photo
from console.security import GuardMiddleware, token_from_headers, token_matches
from console.session import OptionsError, ProviderUnavailable
from console.store import as_step_rows, json_safe

logger = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"
PAGES = {"phone": "phone.html", "console": "console.html", "index": "index.html"}
STATIC_FILES = {"app.css": "text/css", "common.js": "text/javascript", "phone.js": "text/javascript", "console.js": "text/javascript"}


def _error(status: int, code: str, message: str) -> HTTPException:
    return HTTPException(status_code=status, detail={"code": code, "message": message})


def create_app(console: Console, close_on_shutdown: bool = True) -> Any:
    """The ASGI app (FastAPI wrapped in the request guard)."""

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        yield
        if close_on_shutdown:
            await run_in_threadpool(console.close)

    app = FastAPI(
        title="imgnav console",
        description="Upload a goal photo, start a navigation run, follow it live.",
        version="0.1.0",
        lifespan=lifespan,
    )
    app.state.console = console

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail: Any = exc.detail
        if isinstance(detail, str) and exc.status_code == 400:
            # Starlette's form parser answers with bare strings ("Invalid multipart data.");
            # say what is wrong in the API's own error shape.
            detail = {"code": "bad_form", "message": _form_error_message(detail)}
        return JSONResponse({"detail": detail}, status_code=exc.status_code, headers=getattr(exc, "headers", None))

    def require_token(request: Request, form_token: str | None = None) -> None:
        if console.token is None:
            return
        given = token_from_headers(request.headers) or form_token or request.query_params.get("token")
        if not token_matches(console.token, given):
            raise _error(401, "token_required", "this console is reachable from the network: send its token")

    def run_view(row: dict[str, Any]) -> dict[str, Any]:
        out = dict(row)
        out["active"] = console.manager.active_run_id == row["id"]
        out["artifacts"] = {
            name: f"/api/runs/{row['id']}/artifacts/{name}" for name in existing_artifacts(console.data_dir, row["id"])
        }
        return json_safe(out)

    # --- pages ---------------------------------------------------------------

    def page(name: str) -> FileResponse:
        return FileResponse(STATIC_DIR / PAGES[name], media_type="text/html", headers={"cache-control": "no-cache"})

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return page("index")

    @app.get("/phone", include_in_schema=False)
    def phone_page() -> FileResponse:
        return page("phone")

    @app.get("/console", include_in_schema=False)
    def console_page() -> FileResponse:
        return page("console")

    @app.get("/static/{name}", include_in_schema=False)
    def static_file(name: str) -> FileResponse:
        if name not in STATIC_FILES:  # fixed names only: no path from the request reaches the disk
            raise _error(404, "not_found", "no such file")
        return FileResponse(STATIC_DIR / name, media_type=STATIC_FILES[name], headers={"cache-control": "no-cache"})

    @app.get("/favicon.ico", include_in_schema=False)
    def favicon() -> RedirectResponse:
        return RedirectResponse("data:,", status_code=307)

    # --- console-wide ----------------------------------------------------------

    @app.get("/api/config", summary="Backends, viewer and limits")
    def get_config() -> dict[str, Any]:
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

    @app.get("/api/backends/{name}", summary="What a backend offers (homes, starts, gallery)")
    def describe_backend(name: str) -> dict[str, Any]:
        provider = console.providers.get(name)
        if provider is None:
            raise _error(404, "unknown_backend", f"no backend {name!r}; choose one of {sorted(console.providers)}")
        ok, why = provider.available()
        return json_safe({"name": name, "label": provider.label, "available": ok, "why": why, **provider.describe()})

    @app.get("/api/sim/gallery/{home}/{filename}", summary="A gallery goal image of a simulator home")
    def gallery_image(home: str, filename: str) -> FileResponse:
        provider = console.providers.get("sim")
        path = getattr(provider, "gallery_path", lambda h, f: None)(home, filename) if provider else None
        if path is None:
            raise _error(404, "not_found", "no such gallery image")
        return FileResponse(path, media_type="image/png", headers={"cache-control": "max-age=3600"})

    @app.get("/api/sim/episodes/{episode_id}/goal.png", summary="The goal image of an episode of the loaded set")
    def episode_goal(episode_id: str) -> FileResponse:
        provider = console.providers.get("sim")
        path = getattr(provider, "episode_goal_path", lambda e: None)(episode_id) if provider else None
        if path is None:
            raise _error(404, "not_found", "no such episode")
        return FileResponse(path, media_type="image/png")

    # --- runs ----------------------------------------------------------------

    @app.post("/api/runs", status_code=201, summary="Start a run with a goal photo")
    async def start_run(
        request: Request,
        goal_image: Annotated[UploadFile, File(description="the goal photo: JPEG, PNG, WebP or HEIC")],
        backend: Annotated[str | None, Form(description="backend name (default: the simulator)")] = None,
        home: Annotated[str | None, Form(description="simulator home id (default: the first)")] = None,
        start: Annotated[str | None, Form(description="simulator start: a start id, 'x,y,yaw_deg' in the home frame, or 'random'")] = None,
        episode: Annotated[str | None, Form(description="simulator episode id (sets home, start and target)")] = None,
        gallery_item: Annotated[str | None, Form(description="the gallery image the photo was chosen from (makes the target known)")] = None,
        target_instance: Annotated[str | None, Form(description="the target instance id, if known")] = None,
        max_steps: Annotated[int | None, Form(description="step budget (default and maximum: 1000)")] = None,
        token: Annotated[str | None, Form(description="the console token when it is required")] = None,
    ) -> JSONResponse:
        received_s = time.time()
        require_token(request, token)
        name = backend or next(iter(console.providers), "")
        provider = console.providers.get(name)
        if provider is None:
            raise _error(422, "unknown_backend", f"no backend {name!r}; choose one of {sorted(console.providers)}")
        ok, why = provider.available()
        if not ok:
            raise _error(503, "backend_unavailable", f"the {provider.label} cannot be used now: {why}")
        active = console.manager.active_run_id
        if active is not None:  # answer before reading the photo; start() checks again under its lock
            raise _error(409, "run_active", f"run {active} is active; stop it or wait for it to end")
        data = await goal_image.read(console.config.photo_limits.max_bytes + 1)
        try:
            photo = await run_in_threadpool(decode_photo, data, console.config.photo_limits)
        except PhotoError as exc:
            raise _error(exc.status, exc.code, str(exc)) from None
        options = {
            k: v
            for k, v in {
                "home": home,
                "start": start,
                "episode": episode,
                "gallery_item": gallery_item,
                "target_instance": target_instance,
                "max_steps": None if max_steps is None else str(max_steps),
            }.items()
            if v not in (None, "")
        }
        try:
            # in a thread: checking a custom start builds the home's geometry once (~0.5 s)
            resolved = await run_in_threadpool(provider.resolve, options, photo.dhash, photo.sha256)
        except OptionsError as exc:
            raise _error(422, "bad_options", str(exc)) from None
        except ProviderUnavailable as exc:
            raise _error(503, "backend_unavailable", str(exc)) from None
        try:
            run_id = console.manager.start(resolved, photo, data, received_s)
        except RunConflict as exc:
            raise _error(409, "run_active", str(exc)) from None
        except RuntimeError as exc:
            raise _error(503, "shutting_down", str(exc)) from None
        row = console.store.get_run(run_id)
        assert row is not None
        return JSONResponse(run_view(row), status_code=201, headers={"location": f"/api/runs/{run_id}"})

    @app.get("/api/runs", summary="Recent runs, newest first")
    def list_runs(limit: Annotated[int, Query(ge=1, le=500)] = 50, offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0) -> dict[str, Any]:
        return {"runs": [run_view(r) for r in console.store.list_runs(limit, offset)], "active_run": console.manager.active_run_id}

    def get_row(run_id: str) -> dict[str, Any]:
        row = console.store.get_run(run_id) if valid_run_id(run_id) else None
        if row is None:
            raise _error(404, "unknown_run", f"no run {run_id!r}")
        return row

    @app.get("/api/runs/{run_id}", summary="One run (and its steps with ?steps=true)")
    def get_run(run_id: str, steps: bool = False) -> dict[str, Any]:
        out = run_view(get_row(run_id))
        if steps:
            out["steps"] = json_safe(as_step_rows(console.store.steps(run_id)))
        return out

    @app.post("/api/runs/{run_id}/stop", summary="Stop a run after its current step")
    def stop_run(request: Request, run_id: str) -> dict[str, Any]:
        require_token(request)
        row = get_row(run_id)
        stopping = console.manager.stop(run_id)
        if not stopping and row["status"] not in ("finished", "stopped", "failed", "interrupted"):
            # Created but its worker already ended between the two reads: report what is stored.
            row = get_row(run_id)
        return {"run_id": run_id, "stopping": stopping, "status": "stopping" if stopping else row["status"]}

    @app.get("/api/runs/{run_id}/events", summary="Live status of one run (server-sent events)")
    async def run_events(run_id: str) -> StreamingResponse:
        get_row(run_id)
        return StreamingResponse(
            console.hub.subscribe(run_id), media_type="text/event-stream", headers={"cache-control": "no-cache", "x-accel-buffering": "no"}
        )

    @app.get("/api/events", summary="Live status of all runs and console log lines (server-sent events)")
    async def all_events() -> StreamingResponse:
        return StreamingResponse(
            console.hub.subscribe(None), media_type="text/event-stream", headers={"cache-control": "no-cache", "x-accel-buffering": "no"}
        )

    @app.get("/api/runs/{run_id}/artifacts/{name}", summary="A run's file: goal photo, trajectory, map, video")
    def artifact(run_id: str, name: str) -> FileResponse:
        get_row(run_id)
        if name not in ARTIFACT_NAMES:
            raise _error(404, "unknown_artifact", f"no artifact {name!r}; artifacts are {sorted(ARTIFACT_NAMES)}")
        path = run_dir(console.data_dir, run_id) / name
        if not path.is_file():
            raise _error(404, "not_written", f"{name} has not been written for run {run_id}")
        return FileResponse(path, media_type=ARTIFACT_NAMES[name])

    guarded = GuardMiddleware(app, max_bytes=console.config.max_request_bytes)
    # Outermost: a request whose Host header is not a name of this console (DNS rebinding)
    # gets 400 before anything else sees it.
    return TrustedHostMiddleware(guarded, allowed_hosts=console.allowed_hosts, www_redirect=False)


def _form_error_message(parser_message: str) -> str:
    if parser_message.startswith("Invalid multipart data"):
        return (
            "the upload could not be read as a multipart form: a part's header is malformed or too long "
            "(each part header, which holds the file name, must stay under 4 KB; rename a file with a very long name)"
        )
    return f"the upload could not be read as a form: {parser_message}"
