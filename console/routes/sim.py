"""What the simulator offers beyond the generic backend description: gallery images and
episode goal images (typed access to the ``SimProvider``, no ``getattr``)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import FileResponse

from console.context import Console
from console.deps import ConsoleDep, error
from console.sim_provider import SimProvider

router = APIRouter(prefix="/api/sim", tags=["simulator"])


def _sim(console: Console) -> SimProvider:
    provider = console.providers.get("sim")
    if not isinstance(provider, SimProvider):
        raise error(404, "not_found", "this console offers no simulator")
    return provider


@router.get("/gallery/{home}/{filename}", summary="A gallery goal image of a simulator home")
def gallery_image(home: str, filename: str, console: ConsoleDep) -> FileResponse:
    path = _sim(console).gallery_path(home, filename)
    if path is None:
        raise error(404, "not_found", "no such gallery image")
    return FileResponse(path, media_type="image/png", headers={"cache-control": "max-age=3600"})


@router.get("/episodes/{episode_id}/goal.png", summary="The goal image of an episode of the loaded set")
def episode_goal(episode_id: str, console: ConsoleDep) -> FileResponse:
    path = _sim(console).episode_goal_path(episode_id)
    if path is None:
        raise error(404, "not_found", "no such episode")
    return FileResponse(path, media_type="image/png")
