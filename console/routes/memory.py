"""The agent's memory of each home (issue 31; ``console.home_memory``): the simulator's homes and
the robot's home (``console.robot_memory``), each from the backend choice that keeps it
(``console.session.MemoryProvider``): what it holds (its known objects with the goal photo each
was asked with, and for the robot why it was last dropped), the remembered map as a picture,
and forgetting a home. Forgetting goes through the same checks as every other change the console
accepts: the Host check and the same-origin check of every unsafe method (``console.security``),
and the token when the console has one (``TokenDep``).

Asking for a known object again is a run start (``POST /api/runs`` with ``goal_from_run``, the
same route and checks as every run): ``goal_from_run_photo`` and ``check_goal_from_run`` here
say which runs' photos it accepts: a run the home's memory remembers as one of its requests."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from console.artifacts import run_dir, valid_run_id
from console.context import Console
from console.deps import ConsoleDep, TokenDep, error
from console.home_memory import HomeMemories, MemoryInUse
from console.jsonio import json_safe
from console.options import RunForm
from console.session import BackendProvider, MemoryProvider, ResolvedRun

router = APIRouter(prefix="/api/memory", tags=["memory"])


def _memory_keys(console: Console) -> dict[str, list[str]]:
    """Each backend choice that keeps a memory, with its homes."""
    return {
        name: p.memory_keys()
        for name, p in console.providers.items()
        if isinstance(p, MemoryProvider) and p.memory_keys()
    }


def _memories(console: Console, home: str) -> HomeMemories:
    for provider in console.providers.values():
        if isinstance(provider, MemoryProvider) and home in provider.memory_keys():
            return provider.memories()
    homes = [k for keys in _memory_keys(console).values() for k in keys]
    raise error(404, "unknown_home", f"no home {home[:40]!r}; homes are {homes}")


@router.get("", summary="The homes that can have a memory (and each backend's)")
def list_homes(console: ConsoleDep) -> dict[str, Any]:
    by_backend = _memory_keys(console)
    return {"homes": [k for keys in by_backend.values() for k in keys], "backends": by_backend}


@router.get("/{home}", summary="What the agent remembers of a home: keyframes, bytes, known objects")
async def get_memory(home: str, console: ConsoleDep) -> dict[str, Any]:
    memories = _memories(console, home)
    summary = await run_in_threadpool(memories.summary, home)  # the first read loads the file
    summary["map_url"] = f"/api/memory/{home}/map.png"
    for obj in summary["objects"]:
        obj["goal_url"] = _goal_url(console, obj["run_id"])
    return json_safe(summary)


def _goal_url(console: Console, run_id: str | None) -> str | None:
    """The goal photo of the run that asked for an object (the run's own artifact route); None
    when there is no such run (an older memory, the evaluation) or it or its photo is gone."""
    if run_id is None or not valid_run_id(run_id) or console.store.get_run(run_id) is None:
        return None
    if not (run_dir(console.data_dir, run_id) / "goal.png").is_file():
        return None
    return f"/api/runs/{run_id}/artifacts/goal.png"


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


# --- a known object asked for again: POST /api/runs with goal_from_run -----------------------


def goal_from_run_photo(
    console: Console, provider: BackendProvider, run_id: str, form: RunForm, photo_given: bool
) -> tuple[dict[str, Any], bytes]:
    """The stored run named by ``goal_from_run`` and its goal photo (``goal.png``: the photo as its
    agent was given it), after the checks that need no resolved options; a 422 otherwise."""
    if photo_given:
        raise error(422, "two_goals", "send a goal photo (goal_image) or goal_from_run, not both")
    if not isinstance(provider, MemoryProvider) or not provider.memory_keys():
        raise error(422, "no_memory", f"goal_from_run: the {provider.label} keeps no memory of its home")
    if form.memory == "off":
        raise error(422, "memory_off", "goal_from_run asks for a remembered object: the run needs memory on")
    if form.gallery_item is not None:
        raise error(422, "two_goals", "goal_from_run gives that run's goal photo: drop gallery_item")
    row = console.store.get_run(run_id) if valid_run_id(run_id) else None
    if row is None:
        raise error(422, "unknown_run", f"goal_from_run: no run {run_id[:40]!r}")
    path = run_dir(console.data_dir, run_id) / "goal.png"
    if not path.is_file():
        raise error(422, "no_goal_photo", f"goal_from_run: run {run_id} has no goal photo (goal.png) any more")
    return row, path.read_bytes()


def check_goal_from_run(provider: BackendProvider, resolved: ResolvedRun, row: dict[str, Any]) -> None:
    """A run may take the goal photo of ``row``'s run only in that run's home, and only while the
    home's memory remembers that run's request (a 422 otherwise)."""
    assert isinstance(provider, MemoryProvider)  # goal_from_run_photo
    key = provider.run_memory_key(resolved.spec)
    assert key is not None  # memory off is refused by goal_from_run_photo
    source = provider.stored_memory_key(row["options"]) if row["backend"] == provider.name else None
    run_id = row["id"]
    if source != key:
        where = f"in {source}" if source is not None else f"on the {row['backend']} backend"
        raise error(422, "foreign_run", f"goal_from_run: run {run_id} was {where}, not in {key}: ask for it there")
    if not provider.memories().remembers(key, run_id):
        raise error(
            422,
            "not_remembered",
            f"goal_from_run: the memory of {key} holds no request of run {run_id} (forgotten, or run with memory off)",
        )
