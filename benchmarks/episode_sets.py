"""The episode set a benchmark runs on: the one given, or a small one generated for the run."""

from __future__ import annotations

import sys
import tempfile


def load_or_generate(path: str | None, split: str, seed: int, count: int):
    """(EpisodeSet, temporary directory or None): the set at ``path``, or ``count`` episodes of
    ``split``/``seed`` generated into a temporary directory (the caller cleans it up). Warns on
    stderr when a given set is of another split."""
    from sim.episodes import load_episode_set

    tmp = None
    if path is None:
        from sim.episode_gen import generate_episode_set

        tmp = tempfile.TemporaryDirectory()
        path = tmp.name
        generate_episode_set(split, seed, count, path, progress=False)
    es = load_episode_set(path)
    if es.split != split:
        print(f"warning: {path} is a {es.split} set, not {split}", file=sys.stderr)
    return es, tmp
