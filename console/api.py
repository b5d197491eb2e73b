"""The console's HTTP API and pages (FastAPI). OpenAPI docs at /docs.

    GET  /                         landing: phone page on small screens, console page otherwise
    GET  /phone, /console, /calibrate   the pages (static/)
    GET  /api/config               backends and whether they are usable, viewer port, limits
    GET  /api/backends/{name}      what a backend offers (simulator: homes, starts, gallery)
    GET  /api/sim/gallery/{home}/{file}   a gallery goal image
    POST /api/runs                 start a run (multipart: goal_image + options)    -> 201, 409 if busy
    GET  /api/runs                 recent runs (filters: outcome, status, backend, home)
    GET  /api/runs/{id}            one run (with its steps if ?steps=true), its outcome in words
    POST /api/runs/{id}/stop       stop a run after its current step
    GET  /api/runs/{id}/events     live status stream (server-sent events)
    GET  /api/events               all runs' status events and console log lines (SSE)
    GET  /api/runs/{id}/artifacts/{name}   goal photo, trajectory JSON, map PNG, run video
    GET  /api/runs/{id}/replay     a finished run step by step (console.routes.replay)
    /api/calibration/...           a deployment's tau from the operator's own photos
    GET  /api/memory               the homes with a memory (simulator homes, the robot's home)
    GET  /api/memory/{home}        what the agent remembers of a home (map.png: its map)
    DELETE /api/memory/{home}      forget a home

Routers (``console.routes``) receive the console through ``Depends`` (``console.deps``);
the console itself is built in the app's lifespan when ``create_app`` is given a factory
(``imgnav console``), or passed in ready-made (tests).
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.middleware.trustedhost import TrustedHostMiddleware

from console.context import Console, ConsoleConfig
from console.routes import calibration, memory, pages, replay, runs, sim
from console.security import GuardMiddleware, allowed_hosts

logger = logging.getLogger(__name__)


def create_app(
    console: Console | None = None,
    close_on_shutdown: bool = True,
    *,
    build: Callable[[], Console] | None = None,
    config: ConsoleConfig | None = None,
    on_ready: Callable[[Console], None] | None = None,
) -> Any:
    """The ASGI app: FastAPI behind the Host check and the request guard.

    Either ``console`` (built by the caller) or ``build`` with its ``config`` (the console
    is built in the lifespan, before the server accepts requests, and closed after).
    ``on_ready`` runs once the console exists (start-up messages, warm-up)."""
    if (console is None) == (build is None):
        raise ValueError("give create_app either a console or a build function")
    config = console.config if console is not None else config
    if config is None:
        raise ValueError("create_app(build=...) needs the console's config")

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if console is not None:
            built = console
        else:
            assert build is not None  # checked above: exactly one of the two is given
            built = await run_in_threadpool(build)
        app.state.console = built
        if on_ready is not None:
            on_ready(built)
        try:
            yield
        finally:
            if close_on_shutdown:
                await run_in_threadpool(built.close)

    app = FastAPI(
        title="imgnav console",
        description="Upload a goal photo, start a navigation run, follow it live, replay it; calibrate a deployment.",
        version="0.2.0",
        lifespan=lifespan,
    )
    if console is not None:  # usable before the lifespan runs (TestClient without a with-block)
        app.state.console = console

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail: Any = exc.detail
        if isinstance(detail, str) and exc.status_code == 400:
            # Starlette's form parser answers with bare strings ("Invalid multipart data.");
            # say what is wrong in the API's own error shape.
            detail = {"code": "bad_form", "message": _form_error_message(detail)}
        return JSONResponse({"detail": detail}, status_code=exc.status_code, headers=getattr(exc, "headers", None))

    for module in (pages, runs, replay, sim, calibration, memory):
        app.include_router(module.router)

    guarded = GuardMiddleware(app, max_bytes=config.max_request_bytes)
    # Outermost: a request whose Host header is not a name of this console (DNS rebinding)
    # gets 400 before anything else sees it.
    return TrustedHostMiddleware(
        guarded, allowed_hosts=allowed_hosts(config.host, config.allowed_hosts), www_redirect=False
    )


def _form_error_message(parser_message: str) -> str:
    if parser_message.startswith("Invalid multipart data"):
        return (
            "the upload could not be read as a multipart form: a part's header is malformed or too long "
            "(each part header, which holds the file name, must stay under 4 KB; rename a file with a very long name)"
        )
    return f"the upload could not be read as a form: {parser_message}"
