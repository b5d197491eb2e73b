"""FastAPI dependencies shared by the routers: the console, the token check, errors.

The console is built in the app's lifespan and kept on ``app.state``; routes receive it
with ``ConsoleDep``. Routes that can move the robot declare ``TokenDep`` (header, or
``?token=``) or, for multipart forms, check the form's ``token`` field with ``check_token``.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, HTTPException, Request

from console.context import Console
from console.security import token_from_headers, token_matches


def error(status: int, code: str, message: str) -> HTTPException:
    """The API's error shape: ``{"detail": {"code", "message"}}``."""
    return HTTPException(status_code=status, detail={"code": code, "message": message})


def get_console(request: Request) -> Console:
    console = getattr(request.app.state, "console", None)
    if console is None:
        raise error(503, "starting", "the console is still starting")
    return console


ConsoleDep = Annotated[Console, Depends(get_console)]


def check_token(console: Console, request: Request, form_token: str | None = None) -> None:
    if console.token is None:
        return
    given = token_from_headers(request.headers) or form_token or request.query_params.get("token")
    if not token_matches(console.token, given):
        raise error(401, "token_required", "this console is reachable from the network: send its token")


def require_token(request: Request, console: ConsoleDep) -> None:
    check_token(console, request)


TokenDep = Depends(require_token)
