"""The ``imgnav eval`` arguments the Mod-IIN plugin reads, as a namespace (the command's defaults,
overridden by keyword)."""

from __future__ import annotations

import argparse
from typing import Any


def modiin_args(**overrides: Any) -> argparse.Namespace:
    values: dict[str, Any] = dict(
        modiin_config="sim",
        modiin_reid="conf",
        modiin_loc="mask",
        modiin_matcher=None,
        modiin_tau=None,
        modiin_set=[],
        modiin_oracle_min_px=400,
        modiin_seen_px=2300,
        modiin_threads=1,
        workers=1,
    )
    values.update(overrides)
    return argparse.Namespace(**values)
