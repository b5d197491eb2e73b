"""Where tests leave files for a person to look at (browser screenshots): never the checkout.

``IMGNAV_TEST_ARTIFACTS`` names the directory (CI can keep it); by default a directory under the
system's temp dir."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def artifacts_dir(*parts: str) -> Path:
    """The artifacts directory (or a subdirectory of it), not created: callers mkdir it."""
    root = os.environ.get("IMGNAV_TEST_ARTIFACTS") or os.path.join(tempfile.gettempdir(), "imgnav-test-artifacts")
    return Path(root).joinpath(*parts)
