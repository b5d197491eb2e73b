"""The simulator as a backend choice: homes, starts, a gallery of goal images, scoring.

On first start the console prepares a few small homes (``prepare_async``): for each,
a handful of start poses and a gallery of goal images of its instances rendered by
the simulator's goal-image sampler. Everything is cached under ``<data>/sim/`` and
keyed by the simulator's generator version, so later starts load in milliseconds.

A run's target instance is known, and the run is scored (success, SPL, NE), when
* the page says which gallery image the photo came from (``gallery_item``), or
* the photo is a gallery image re-encoded or resized (perceptual hash within
  ``DHASH_MAX_BITS`` of a gallery image of the chosen home), or
* an episode is chosen, or ``target_instance`` is given.
Otherwise the run is unscored and its outcome says so.

Runs in the same home share the agent's memory of that home (``console.home_memory``: one
per home, kept in ``<data>/memory/``, never given to a run in another home).

The simulator-specific calls live in ``console.sim_adapter``.
"""

from __future__ import annotations

import functools
import json
import logging
import math
import re
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agent.types import MAX_STEPS
from console.home_memory import HomeMemories, HomeSlot, home_key
from console.options import RunForm, RunOptions, SimRunOptions
from console.photos import hamming
from console.session import OptionsError, ProviderUnavailable, ResolvedRun, RunSession, check_memory_option
from console.sim_catalog import GalleryItem, HomeEntry, Start
from sim.realism import Realism

logger = logging.getLogger(__name__)

DHASH_MAX_BITS = 6  # of 64: re-encodings and resizes stay within ~4 bits, other pictures differ by ~32
CATALOG_VERSION = 1
_ITEM = re.compile(r"^(home-\d+)/(i\d+-v\d+)$")
_FILE = re.compile(r"^i\d+-v\d+\.png$")


@dataclass(frozen=True, slots=True)
class SimProviderConfig:
    home_seeds: tuple[int, ...] = (0, 1)
    n_rooms: int = 3  # small homes: quick to build, quick to explore
    views_per_instance: int = 1
    starts_per_home: int = 4
    agent_config_path: Path | None = None  # None: the agent's sim deployment YAML
    episodes_dir: Path | None = None  # an episode set (``imgnav episodes``) offered as run choices
    realism: Realism | None = None  # the simulated robot's noise (``--realism``); None: exact


class SimProvider:
    name = "sim"
    label = "Simulator (PyBullet home)"

    def __init__(self, data_dir: Path, config: SimProviderConfig = SimProviderConfig()) -> None:
        self.dir = Path(data_dir) / "sim"
        self.config = config
        if config.realism is not None:
            self.label = f"Simulator (PyBullet home, {config.realism.profile.name} realism)"
        self._lock = threading.Lock()
        self._homes: dict[str, HomeEntry] = {}
        self._ready = False
        self._error: str | None = None
        self._progress = "not prepared yet"
        self._thread: threading.Thread | None = None
        self._episodes: Any = None
        self._worlds: Any = None  # sim_cache.WorldCache, made on first use (imports sim/)
        self._memories: HomeMemories | None = None  # made on first use (reads the agent config)
        self._memory_dir = Path(data_dir) / "memory"
        if config.episodes_dir is not None:
            from sim.episodes import load_episode_set

            self._episodes = load_episode_set(config.episodes_dir)
            logger.info("offering %d episodes from %s", len(self._episodes), config.episodes_dir)
        self._load_cache()

    # --- preparation ---------------------------------------------------------

    def _cache_path(self) -> Path:
        return self.dir / "catalog.json"

    def _cache_key(self) -> dict[str, Any]:
        from console import sim_adapter

        return {
            "catalog_version": CATALOG_VERSION,
            "simulator": sim_adapter.generator_version(),
            "homes": [sim_adapter.home_fingerprint(seed, self.config.n_rooms) for seed in self.config.home_seeds],
            "seeds": list(self.config.home_seeds),
            "n_rooms": self.config.n_rooms,
            "views_per_instance": self.config.views_per_instance,
            "starts_per_home": self.config.starts_per_home,
        }

    def _load_cache(self) -> None:
        path = self._cache_path()
        if not path.is_file():
            return
        try:
            doc = json.loads(path.read_text())
            if doc.get("key") != self._cache_key():
                logger.info("simulator gallery cache is stale; it will be rebuilt")
                return
            homes = [HomeEntry.from_json(h) for h in doc["homes"]]
        except (ValueError, KeyError, TypeError) as exc:
            logger.warning("ignoring unreadable simulator cache %s: %s", path, exc)
            return
        missing = [g.file for h in homes for g in h.gallery if not (self.dir / h.id / g.file).is_file()]
        if missing:
            logger.info("simulator gallery cache lacks %d images; it will be rebuilt", len(missing))
            return
        with self._lock:
            self._homes = {h.id: h for h in homes}
            self._ready = True
            self._progress = f"{len(homes)} homes ready (cached)"

    def prepare_async(self, hub: Any | None = None) -> threading.Thread:
        """Build homes and gallery in the background (skipped when cached), then the first home's
        world for the first run. Progress goes to the log and, as ``log`` events, to the console page."""

        def work() -> None:
            if self._ready:
                self._log(hub, self._progress, ready=True)
            else:
                self.prepare(hub)
            if self._ready:
                try:
                    self.warm_up()
                except Exception:  # the first run builds (and reports) it instead
                    logger.exception("building the first simulator home ahead of the first run failed")

        self._thread = threading.Thread(target=work, name="sim-prepare", daemon=True)
        self._thread.start()
        return self._thread

    def prepare(self, hub: Any | None = None) -> None:
        from console import sim_adapter

        if self._ready:
            return
        t0 = time.perf_counter()
        homes: list[HomeEntry] = []
        try:
            for k, seed in enumerate(self.config.home_seeds):
                home_id = f"home-{seed}"
                self._log(hub, f"preparing simulator home {k + 1}/{len(self.config.home_seeds)} (seed {seed})")
                entry = sim_adapter.build_home_entry(
                    seed=seed,
                    home_id=home_id,
                    out_dir=self.dir / home_id,
                    n_rooms=self.config.n_rooms,
                    views_per_instance=self.config.views_per_instance,
                    n_starts=self.config.starts_per_home,
                    progress=functools.partial(self._log_home, hub, home_id),
                )
                homes.append(entry)
            doc = {"key": self._cache_key(), "homes": [h.to_json() for h in homes]}
            self.dir.mkdir(parents=True, exist_ok=True)
            tmp = self._cache_path().with_suffix(".tmp")
            tmp.write_text(json.dumps(doc, indent=1))
            tmp.replace(self._cache_path())
        except Exception as exc:  # preparation failing must not kill the console; the page shows why
            logger.exception("preparing the simulator failed")
            with self._lock:
                self._error = f"preparing the simulator failed: {type(exc).__name__}: {exc}"
            self._log(hub, self._error)
            return
        with self._lock:
            self._homes = {h.id: h for h in homes}
            self._ready = True
            self._progress = f"{len(homes)} homes ready in {time.perf_counter() - t0:.1f} s"
        self._log(hub, self._progress, ready=True)

    def wait_ready(self, timeout_s: float) -> bool:
        if self._thread is not None:
            self._thread.join(timeout_s)
        return self._ready

    def _log_home(self, hub: Any | None, home_id: str, message: str) -> None:
        """A home builder's progress line, named by its home."""
        self._log(hub, f"{home_id}: {message}")

    def _log(self, hub: Any | None, message: str, ready: bool = False) -> None:
        logger.info("%s", message)
        with self._lock:
            self._progress = message
        if hub is not None:
            hub.publish("log", None, {"message": message, "ready": ready, "source": "sim"})

    # --- BackendProvider -----------------------------------------------------

    def available(self) -> tuple[bool, str]:
        with self._lock:
            if self._error:
                return False, self._error
            if not self._ready:
                return False, f"preparing homes ({self._progress})"
        return True, ""

    @property
    def homes(self) -> dict[str, HomeEntry]:
        with self._lock:
            return dict(self._homes)

    def describe(self) -> Mapping[str, Any]:
        homes = []
        for h in self.homes.values():
            homes.append(
                {
                    "id": h.id,
                    "label": h.label,
                    "starts": [{"id": s.id, "label": s.label} for s in h.starts]
                    + [{"id": "random", "label": "random"}],
                    "gallery": [
                        {
                            "item": g.item,
                            "instance": g.instance_id,
                            "category": g.category,
                            "label": g.label,
                            "url": f"/api/sim/gallery/{h.id}/{g.file}",
                            "default_start": _search_start(h, g),
                        }
                        for g in h.gallery
                    ],
                }
            )
        episodes = []
        if self._episodes is not None:
            for e in self._episodes:
                episodes.append(
                    {
                        "id": e.episode_id,
                        "label": f"{e.episode_id}: {e.goal_category} in scene {e.scene_seed} ({e.geodesic_distance_m:.1f} m)",
                        "goal_image_url": f"/api/sim/episodes/{e.episode_id}/goal.png",
                    }
                )
        return {"homes": homes, "episodes": episodes, "progress": self._progress}

    def episode_goal_path(self, episode_id: str) -> Path | None:
        if self._episodes is None:
            return None
        try:
            episode = self._episodes.by_id(episode_id)
        except KeyError:
            return None
        path = self._episodes.goal_image_path(episode)
        return path if path.is_file() else None

    def gallery_path(self, home_id: str, filename: str) -> Path | None:
        home = self.homes.get(home_id)
        if home is None or not _FILE.match(filename) or all(g.file != filename for g in home.gallery):
            return None
        path = self.dir / home.id / filename
        return path if path.is_file() else None

    def resolve(self, form: RunForm, goal_dhash: int, goal_sha256: str) -> ResolvedRun:
        homes = self.homes
        if not homes:
            raise ProviderUnavailable("the simulator has no homes prepared yet")
        if form.episode is not None:
            return self._resolve_episode(form)
        home_id = form.home or next(iter(homes))
        home = homes.get(home_id)
        if home is None:
            raise OptionsError(f"no home {home_id!r}; homes are {sorted(homes)}")
        start = _parse_start(home, form.start)
        if start.id == "custom":
            from console import sim_adapter

            x, y, _ = start.pose_world
            if sim_adapter.start_collides(home.seed, self.config.n_rooms, x, y):
                raise OptionsError(
                    f"start ({_shown_m(x)}, {_shown_m(y)}) is not a free position in {home.id}: the robot (radius 0.17 m) "
                    "would overlap a wall or furniture there, or it is outside the home"
                )
        max_steps = _check_max_steps(form.max_steps)
        memory = check_memory_option(form.memory)

        target: dict[str, Any] | None = None
        if form.gallery_item:
            m = _ITEM.match(form.gallery_item)
            found = next((g for g in home.gallery if g.item == form.gallery_item), None) if m else None
            if found is None:
                raise OptionsError(f"no gallery image {form.gallery_item!r} in {home.id}")
            target = _target(found, "gallery_item")
        elif form.target_instance is not None:
            try:
                iid = int(form.target_instance)
            except ValueError:
                raise OptionsError("target_instance must be an integer instance id") from None
            found = next((g for g in home.gallery if g.instance_id == iid), None)
            if found is None:
                raise OptionsError(f"{home.id} has no goal instance {iid}")
            target = _target(found, "target_instance")
        else:
            best = min(home.gallery, key=lambda g: hamming(int(g.dhash, 16), goal_dhash), default=None)
            if best is not None:
                dist = hamming(int(best.dhash, 16), goal_dhash)
                if dist <= DHASH_MAX_BITS:
                    target = _target(best, f"perceptual hash ({dist} of 64 bits differ)")
        spec = SimRunOptions(
            home=home.id,
            home_seed=home.seed,
            start=start.id,
            start_pose_world=start.pose_world,
            max_steps=max_steps,
            memory=memory,
        )
        return ResolvedRun("sim", spec, target)

    def _resolve_episode(self, form: RunForm) -> ResolvedRun:
        """An episode fixes the home, the start and the target; the photo is the goal image
        (the episode's own, or any other picture of the same instance)."""
        if self._episodes is None:
            raise OptionsError("no episode set is loaded (start the console with --episodes DIR)")
        extra = form.given() - {"episode", "max_steps", "memory"}
        if extra:
            raise OptionsError(f"an episode fixes home, start and target; drop {sorted(extra)}")
        try:
            e = self._episodes.by_id(form.episode)
        except KeyError:
            raise OptionsError(f"no episode {form.episode!r}") from None
        spec = SimRunOptions(
            episode=e.episode_id,
            episodes_dir=str(self.config.episodes_dir),
            home_seed=e.scene_seed,
            start_pose_world=tuple(e.start_pose_world.as_tuple()),
            max_steps=_check_max_steps(form.max_steps),
            memory=check_memory_option(form.memory),
        )
        target = {
            "instance_id": e.goal_instance_id,
            "category": e.goal_category,
            "episode": e.episode_id,
            "geodesic_distance_m": e.geodesic_distance_m,
            "identified_by": "episode",
        }
        return ResolvedRun("sim", spec, target)

    def worlds(self) -> Any:
        from console import sim_adapter

        with self._lock:
            if self._worlds is None:
                self._worlds = sim_adapter.WorldCache()
            return self._worlds

    def warm_up(self) -> float:
        """Build the first home's world ahead of the first run; returns seconds."""
        from console import sim_adapter

        homes = self.homes
        if not homes:
            return 0.0
        first = next(iter(homes.values()))
        t0 = time.perf_counter()
        self.worlds().warm(
            ("home", first.seed, self.config.n_rooms), lambda: sim_adapter._world(first.seed, self.config.n_rooms)
        )
        seconds = time.perf_counter() - t0
        logger.info("simulator home %s built ahead of the first run in %.1f s", first.id, seconds)
        return seconds

    def memories(self) -> HomeMemories:
        """The memories of the homes (``console.home_memory``), for the agent config's memory
        bounds, mapping and matcher."""
        with self._lock:
            if self._memories is None:
                from agent.config import load_agent_config

                config = load_agent_config(self.config.agent_config_path or "sim")
                self._memories = HomeMemories(self._memory_dir, config.memory, config.mapping, config.reid.matcher)
            return self._memories

    def memory_keys(self) -> list[str]:
        """The homes that can have a memory: the catalogue's homes and the loaded episodes' scenes."""
        keys = [home_key("home", h.seed) for h in self.homes.values()]
        if self._episodes is not None:
            keys += sorted({home_key("scene", e.scene_seed) for e in self._episodes})
        return keys

    @staticmethod
    def memory_key(spec: SimRunOptions) -> str:
        """The home a run is in: ``scene-<seed>`` for an episode (the full-size home), else ``home-<seed>``."""
        return home_key("scene" if spec.episode is not None else "home", spec.home_seed)

    def run_memory_key(self, spec: RunOptions) -> str | None:
        """``memory_key`` of a simulator run's options; None with memory off."""
        if not isinstance(spec, SimRunOptions) or spec.memory == "off":
            return None
        return self.memory_key(spec)

    @staticmethod
    def stored_memory_key(options: Mapping[str, Any]) -> str | None:
        """``memory_key`` of a stored run's options (``SimRunOptions.to_json``); None when they
        are not a simulator run's."""
        seed = options.get("home_seed")
        if type(seed) is not int:
            return None
        try:
            return home_key("scene" if options.get("episode") is not None else "home", seed)
        except ValueError:  # a seed no home key has
            return None

    def open(self, resolved: ResolvedRun, goal_rgb: np.ndarray) -> RunSession:
        spec = resolved.spec
        assert isinstance(spec, SimRunOptions), spec
        if spec.memory == "off":  # from nothing, the home's memory left as it was
            return self._open(resolved, spec, goal_rgb, None, None)
        memories = self.memories()
        slot = memories.acquire(self.memory_key(spec), resolved.run_id)
        try:
            return self._open(resolved, spec, goal_rgb, slot, lambda: memories.release(slot))
        except BaseException:
            memories.release(slot, save=False)
            raise

    def _open(
        self,
        resolved: ResolvedRun,
        spec: SimRunOptions,
        goal_rgb: np.ndarray,
        slot: HomeSlot | None,
        on_close: Any,
    ) -> RunSession:
        from console import sim_adapter

        if spec.episode is not None:
            return sim_adapter.open_episode_session(
                episode=self._episodes.by_id(spec.episode),
                goal_rgb=goal_rgb,
                max_steps=spec.max_steps,
                agent_config_path=self.config.agent_config_path,
                worlds=self.worlds(),
                realism=self.config.realism,
                memory=slot,
                on_close=on_close,
            )
        target = resolved.target
        return sim_adapter.open_session(
            home_seed=spec.home_seed,
            n_rooms=self.config.n_rooms,
            start_pose_world=spec.start_pose_world,
            goal_rgb=goal_rgb,
            target_instance_id=None if target is None else int(target["instance_id"]),
            max_steps=spec.max_steps,
            agent_config_path=self.config.agent_config_path,
            worlds=self.worlds(),
            realism=self.config.realism,
            run_key=f"home-{spec.home_seed}-{spec.start_pose_world}",  # a start's noise is repeatable
            memory=slot,
            on_close=on_close,
        )

    def close(self) -> None:
        if self._worlds is not None:
            self._worlds.close()


def _search_start(home: HomeEntry, g: GalleryItem) -> str | None:
    """The room-middle start farthest from the item's object, so that a demo makes a real search
    (the first start can be right next to the first gallery object). The object's position is
    approximated by its "near" start (1.2-2.2 m from it)."""
    near = next((s for s in home.starts if s.id == f"n{g.instance_id}"), None)
    rooms = [s for s in home.starts if s.id.startswith("r")]
    if near is None or not rooms:
        return None
    far = max(
        rooms, key=lambda s: math.hypot(s.pose_world[0] - near.pose_world[0], s.pose_world[1] - near.pose_world[1])
    )
    return far.id


def _target(g: GalleryItem, identified_by: str) -> dict[str, Any]:
    return {
        "instance_id": g.instance_id,
        "category": g.category,
        "room": g.room,
        "gallery_item": g.item,
        "identified_by": identified_by,
    }


def _parse_start(home: HomeEntry, text: str | None) -> Start:
    if not text:
        return home.starts[0]
    for s in home.starts:
        if s.id == text:
            return s
    if text == "random":
        rng = np.random.default_rng()
        s = home.starts[int(rng.integers(len(home.starts)))]
        return Start(s.id, s.label, (s.pose_world[0], s.pose_world[1], float(rng.uniform(-math.pi, math.pi))))
    parts = text.split(",")
    if len(parts) == 3:
        try:
            x, y, yaw_deg = (float(p) for p in parts)
        except ValueError:
            raise OptionsError(f"start {text!r}: expected 'x,y,yaw_deg' in metres and degrees") from None
        if not all(math.isfinite(v) for v in (x, y, yaw_deg)):
            raise OptionsError(f"start {text!r} is not finite")
        return Start(
            "custom", f"({_shown_m(x)}, {_shown_m(y)}, {_shown_m(yaw_deg, 0)} deg)", (x, y, math.radians(yaw_deg))
        )
    raise OptionsError(
        f"no start {text!r} in {home.id}; starts are {[s.id for s in home.starts]}, 'random' or 'x,y,yaw_deg'"
    )


def _shown_m(v: float, digits: int = 2) -> str:
    """A number as a message shows it: 1e308 as "1e+308", not its 309 digits (issue 33)."""
    return f"{v:.{digits}f}" if abs(v) < 1e6 else f"{v:.3g}"


def _check_max_steps(n: int | None) -> int:
    if n is None:
        return MAX_STEPS
    if not 1 <= n <= MAX_STEPS:
        raise OptionsError(f"max_steps must be between 1 and {MAX_STEPS}")
    return n
