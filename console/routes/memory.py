"""The agent's memory of each simulator home (issue 31; ``console.home_memory``): what it holds,
the remembered map as a picture, and forgetting a home. Forgetting goes through the same checks
as every other change the console accepts: the Host check and the same-origin check of every
unsafe method (``console.security``), and the token when the console has one (``TokenDep``)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from console.context import Console
from console.deps import ConsoleDep, TokenDep, error
from console.home_memory import HomeMemories, MemoryInUse
from console.jsonio import json_safe
from console.routes.sim import _sim

router = APIRouter(prefix="/api/memory", tags=["memory"])


def _memories(console: Console, home: str) -> HomeMemories:
    provider = _sim(console)
    if home not in provider.memory_keys():
        raise error(404, "unknown_home", f"no home {home!r}; homes are {provider.memory_keys()}")
    return provider.memories()


@router.get("", summary="The homes that can have a memory")
def list_homes(console: ConsoleDep) -> dict[str, Any]:
    return {"homes": _sim(console).memory_keys()}


@router.get("/{home}", summary="What the agent remembers of a home: keyframes, bytes, known objects")
async def get_memory(home: str, console: ConsoleDep) -> dict[str, Any]:
    memories = _memories(console, home)
    summary = await run_in_threadpool(memories.summary, home)  # the first read loads the file
    summary["map_url"] = f"/api/memory/{home}/map.png"
    return json_safe(summary)


@router.get("/{home}/map.png", summary="The remembered map with the known objects")
async def memory_map(home: str, console: ConsoleDep) -> Response:
    memories = _memories(console, home)
    png = await run_in_threadpool(memories.map_png, home)
    return Response(png, media_type="image/png", headers={"cache-control": "no-store"})


@router.delete("/{home}", summary="Forget a home (409 while a run uses its memory)", dependencies=[TokenDep])
async def forget_memory(home: str, console: ConsoleDep) -> dict[str, Any]:
    memories = _memories(console, home)
    try:
        forgotten = await run_in_threadpool(memories.forget, home)
    except MemoryInUse as exc:
        raise error(409, "memory_in_use", str(exc)) from None
    return {"home": home, "forgotten": forgotten}
