"""The pages (static/, no build step) and their files."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

from console.deps import error

STATIC_DIR = Path(__file__).resolve().parents[2] / "static"
PAGES = {"phone": "phone.html", "console": "console.html", "index": "index.html", "calibrate": "calibrate.html"}
STATIC_FILES = {
    "app.css": "text/css",
    "common.js": "text/javascript",
    "phone.js": "text/javascript",
    "console.js": "text/javascript",
    "replay.js": "text/javascript",
    "calibrate.js": "text/javascript",
    "favicon.svg": "image/svg+xml",
}

router = APIRouter(include_in_schema=False)


def _page(name: str) -> FileResponse:
    return FileResponse(STATIC_DIR / PAGES[name], media_type="text/html", headers={"cache-control": "no-cache"})


@router.get("/")
def index() -> FileResponse:
    return _page("index")


@router.get("/phone")
def phone_page() -> FileResponse:
    return _page("phone")


@router.get("/console")
def console_page() -> FileResponse:
    return _page("console")


@router.get("/calibrate")
def calibrate_page() -> FileResponse:
    return _page("calibrate")


@router.get("/static/{name}")
def static_file(name: str) -> FileResponse:
    if name not in STATIC_FILES:  # fixed names only: no path from the request reaches the disk
        raise error(404, "not_found", "no such file")
    return FileResponse(STATIC_DIR / name, media_type=STATIC_FILES[name], headers={"cache-control": "no-cache"})


@router.get("/favicon.ico")
def favicon() -> FileResponse:
    # An SVG icon (browsers accept it by its content type); a redirect to data: was a console error.
    return FileResponse(
        STATIC_DIR / "favicon.svg", media_type="image/svg+xml", headers={"cache-control": "max-age=86400"}
    )
