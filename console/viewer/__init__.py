"""The live 3D view: a viser server showing the active run (read-only, plus a stop button) and,
on request, a finished run step by step. ``Viewer`` (``server``) puts the parts together: the
handshake guard, the per-browser stop controls, the live scene, the publishing thread and the
replay GUI, one module each."""

from console.viewer.config import ViewerConfig
from console.viewer.server import Viewer

__all__ = ["Viewer", "ViewerConfig"]
