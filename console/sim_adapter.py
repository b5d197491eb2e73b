"""The console's calls into the simulator (``sim/``), in one place.

* ``build_home_entry``: build a small home, pick start poses (one per room, one near
  each goal instance) and render its gallery with the simulator's goal-image sampler.
* ``open_session``: a ``SimBackend`` for a start pose and any goal image (with the
  target instance when it is known, so the run can be scored) and a Mod-IIN agent.
  With the console's ``WorldCache`` (``console.sim_cache``) the home stays built between
  runs, and so do its start frames and the scoring data of its targets.
* With a ``HomeSlot`` (``console.home_memory``) the run's agent starts from the home's memory and
  its backend reports poses in the memory's frame (``agent.memory.InHomeFrame``).
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from agent.types import Action, Agent, Pose2D
from console.agents import build_agent
from console.home_memory import HomeSlot
from console.photos import dhash
from console.session import Outcome, close_run
from console.sim_cache import WorldCache, kept_scoring, kept_start_render
from console.sim_catalog import GalleryItem, HomeEntry, Start
from sim.realism import Realism

logger = logging.getLogger(__name__)

START_CLEARANCE_M = 0.25  # free space around a start beyond the robot's own footprint
NEAR_START_RANGE_M = (1.2, 2.2)  # "near <instance>" starts: this far from the instance centre


def generator_version() -> Any:
    from sim.scene_gen import GENERATOR_VERSION

    return GENERATOR_VERSION


def home_fingerprint(seed: int, n_rooms: int) -> str:
    """A digest of the generated home (rooms, objects and their poses): the gallery cache is
    rebuilt when the generator's output changes, even without a version bump."""
    import hashlib

    from sim.scene_gen import generate_home

    home = generate_home(seed, n_rooms=n_rooms)
    facts = [(r.name, r.rect_m) for r in home.rooms] + [
        (o.object_id, o.category, o.variant, o.pose_xy_yaw) for o in home.objects
    ]
    return hashlib.sha256(repr(facts).encode()).hexdigest()[:16]


def start_collides(seed: int, n_rooms: int, x_m: float, y_m: float) -> bool:
    """Whether the robot's disc at (x_m, y_m) in the home frame overlaps the scene or lies
    outside the home: the same test ``SimBackend`` applies to its start pose, from geometry
    alone (no PyBullet world is built)."""
    return _footprints(seed, n_rooms).collides(x_m, y_m)


@functools.lru_cache(maxsize=8)
def _footprints(seed: int, n_rooms: int) -> Any:
    from sim.geometry import FootprintIndex
    from sim.scene_gen import generate_home

    home = generate_home(seed, n_rooms=n_rooms)
    x0, y0, x1, y1 = home.bounds_m
    return FootprintIndex(home.solid_footprints(), (x0, y0, x1, y1))


def _world(seed: int, n_rooms: int) -> Any:
    from sim.scene_gen import generate_home
    from sim.world import SimWorld

    return SimWorld(generate_home(seed, n_rooms=n_rooms))


def _clear_cells(world: Any) -> tuple[Any, np.ndarray]:
    from scipy.ndimage import binary_erosion

    grid = world.navigable_grid(0.05)
    cells = int(round(START_CLEARANCE_M / grid.resolution_m))
    clear = binary_erosion(grid.navigable, iterations=cells)
    return grid, clear if clear.any() else grid.navigable


def _starts(world: Any, rng: np.random.Generator) -> list[tuple[str, str, tuple[float, float, float]]]:
    """(id, label, pose_world) for the navigable point nearest each room's centre, facing
    the room's longer side (the view that shows most of the room at the first step)."""
    grid, clear = _clear_cells(world)
    xs, ys = grid.cell_centres()
    out = []
    for room in world.home.rooms:
        cx, cy = room.center_xy_m
        inside = clear & np.vectorize(room.contains)(xs, ys) if clear.size < 200_000 else clear
        if not inside.any():
            continue
        d2 = np.where(inside, (xs - cx) ** 2 + (ys - cy) ** 2, np.inf)
        i, j = np.unravel_index(int(np.argmin(d2)), d2.shape)
        yaw = float(rng.uniform(-math.pi, math.pi))
        out.append((f"r{room.index}", f"{room.name} (middle)", (float(xs[i, j]), float(ys[i, j]), yaw)))
    return out


def _near_start(world: Any, instance: Any, rng: np.random.Generator) -> tuple[float, float, float] | None:
    """A clear cell 1.2-2.2 m from the instance, facing it (short runs for tests and demos)."""
    grid, clear = _clear_cells(world)
    xs, ys = grid.cell_centres()
    cx, cy, _ = instance.center_xyz_m()
    d = np.hypot(xs - cx, ys - cy)
    ok = clear & (d >= NEAR_START_RANGE_M[0]) & (d <= NEAR_START_RANGE_M[1])
    room = world.home.room_at(cx, cy)
    if room is not None:
        same_room = ok & np.vectorize(room.contains)(xs, ys)
        ok = same_room if same_room.any() else ok
    cells = np.argwhere(ok)
    if len(cells) == 0:
        return None
    i, j = cells[int(rng.integers(len(cells)))]
    x, y = float(xs[i, j]), float(ys[i, j])
    return (x, y, math.atan2(cy - y, cx - x))


def build_home_entry(
    *,
    seed: int,
    home_id: str,
    out_dir: Path,
    n_rooms: int,
    views_per_instance: int,
    n_starts: int,
    progress: Callable[[str], None],
) -> HomeEntry:
    """Build one home's catalog entry and write its gallery PNGs into ``out_dir``."""
    from sim.goals import sample_goal_images

    out_dir.mkdir(parents=True, exist_ok=True)
    world = _world(seed, n_rooms)
    try:
        rng = np.random.default_rng(seed)
        starts = [Start(*s) for s in _starts(world, rng)[:n_starts]]
        gallery: list[GalleryItem] = []
        instances = world.home.instances
        progress(f"{len(world.home.rooms)} rooms, {len(instances)} goal instances; rendering the gallery")
        for inst in instances:
            room = world.home.rooms[inst.room_index].name
            images = sample_goal_images(world, inst.object_id, views_per_instance, (seed, inst.object_id))
            if not images:
                logger.info(
                    "home %d: no acceptable goal view of instance %d; left out of the gallery", seed, inst.object_id
                )
            for v, goal in enumerate(images):
                rgb = goal.rgb
                name = f"i{inst.object_id}-v{v}"
                Image.fromarray(rgb).save(out_dir / f"{name}.png")
                gallery.append(
                    GalleryItem(
                        item=f"{home_id}/{name}",
                        instance_id=int(inst.object_id),
                        category=inst.category,
                        room=room,
                        label=f"{inst.category} #{inst.object_id} ({room})",
                        file=f"{name}.png",
                        dhash=f"{dhash(rgb):016x}",
                    )
                )
            near = _near_start(world, inst, rng)
            if near is not None:
                starts.append(Start(f"n{inst.object_id}", f"near {inst.category} #{inst.object_id} ({room})", near))
        if not starts:
            raise RuntimeError(f"home {seed} has no clear start position")
        progress(f"{len(gallery)} gallery images, {len(starts)} starts")
        return HomeEntry(
            id=home_id,
            seed=seed,
            label=f"Home {seed} ({len(world.home.rooms)} rooms: {', '.join(r.name for r in world.home.rooms)})",
            rooms=len(world.home.rooms),
            starts=tuple(starts),
            gallery=tuple(gallery),
        )
    finally:
        world.close()


@dataclass
class SimSession:
    """A SimBackend and a Mod-IIN agent for one console run."""

    backend: Any
    agent: Agent
    agent_config: Mapping[str, Any] = field(default_factory=dict)
    target_known: bool = False
    open_timings: Mapping[str, float] = field(default_factory=dict)  # open_backend_s, open_agent_s
    # with a home memory: ``backend`` is the SimBackend in the memory's frame, this the SimBackend itself
    sim_backend: Any = None
    on_close: Callable[[], None] | None = None  # after the backend is closed (the memory is saved)

    def outcome(self, last_action: Action | None, reason: str) -> Outcome:
        if reason == "operator":
            detail = "stopped by the operator"
            outcome = "stopped"
        elif reason == "agent":
            detail = "the agent stopped"
            outcome = "unscored"
        else:
            detail = "the step budget ran out"
            outcome = "unscored"
        if not self.target_known:
            return Outcome(outcome, f"{detail}; the goal photo's instance is unknown, so the run is not scored")
        sim = self.sim_backend if self.sim_backend is not None else self.backend
        metrics = _metrics(sim.result())  # None while the episode is not over
        if outcome == "stopped":
            return Outcome("stopped", f"{detail}; a stopped run is not scored", metrics or None)
        success = bool(metrics.get("success")) if metrics else False
        return Outcome("success" if success else "failure", detail, metrics)

    def close(self) -> None:
        close_run(self.backend, self.on_close)


def _metrics(result: Any) -> dict[str, Any]:
    if result is None:
        return {}
    if isinstance(result, Mapping):
        return dict(result)
    import dataclasses

    if dataclasses.is_dataclass(result) and not isinstance(result, type):
        return dataclasses.asdict(result)
    return {"result": str(result)}


def open_session(
    *,
    home_seed: int,
    n_rooms: int,
    start_pose_world: tuple[float, float, float],
    goal_rgb: np.ndarray,
    target_instance_id: int | None,
    max_steps: int,
    agent_config_path: Path | None,
    worlds: WorldCache | None = None,
    realism: Realism | None = None,
    run_key: str | None = None,
    memory: HomeSlot | None = None,
    on_close: Callable[[], None] | None = None,
) -> SimSession:
    from sim.backend import SimBackend
    from sim.camera import SIM_CAMERA

    t0 = time.perf_counter()
    key = ("home", home_seed, n_rooms)
    start = Pose2D(*start_pose_world)
    extra: dict[str, Any] = {}
    if worlds is None:  # a world of its own, closed with the backend
        world, owns = _world(home_seed, n_rooms), True
    else:  # the console's warm world: kept for the next run, with its start frames and scoring data
        world, owns = worlds.get(key, lambda: _world(home_seed, n_rooms)), False
        extra["start_render"] = kept_start_render(worlds, key, world, start, SIM_CAMERA)
        if target_instance_id is not None:
            extra["scoring"] = kept_scoring(worlds, key, world, target_instance_id, start)
    # The backend's step budget is the run's, so a run that spends it is over for the
    # backend too and can be scored.
    return _session(
        t0,
        world,
        owns,
        lambda: SimBackend(
            world,
            goal_rgb,
            start,
            goal_instance_id=target_instance_id,
            max_steps=max_steps,
            owns_world=owns,
            camera=SIM_CAMERA,
            realism=realism,
            run_key=run_key,
            **extra,
        ),
        agent_config_path,
        target_known=target_instance_id is not None,
        memory=memory,
        start_world=start,
        on_close=on_close,
    )


def _session(
    t0: float,
    world: Any,
    owns: bool,
    make_backend: Callable[[], Any],
    agent_config_path: Path | None,
    target_known: bool,
    memory: HomeSlot | None = None,
    start_world: Pose2D | None = None,
    on_close: Callable[[], None] | None = None,
) -> SimSession:
    """The backend and the agent of a run; a world of the run's own is closed if either fails.
    With ``memory``: the agent gets the home's memory and the backend is seen in its frame, the
    origin being this run's true start (``start_world``) in that frame (``HomeSlot.origin_for``:
    in the simulator's warm home the true start poses stand for the odometry of a robot that
    keeps its map between requests)."""
    from agent.memory import InHomeFrame

    try:
        backend = make_backend()
        t1 = time.perf_counter()
        agent, agent_config = build_agent(
            agent_config_path or "sim", home_memory=None if memory is None else memory.memory
        )
    except BaseException:
        if owns:
            world.close()
        raise
    timings = {"open_backend_s": t1 - t0, "open_agent_s": time.perf_counter() - t1}
    if memory is None:
        return SimSession(
            backend, agent, agent_config, target_known=target_known, open_timings=timings, on_close=on_close
        )
    assert start_world is not None
    origin = memory.origin_for(start_world)
    agent_config = {
        **agent_config,
        "memory_home": memory.key,
        "memory_origin": [origin.x_m, origin.y_m, origin.yaw_rad],
    }
    return SimSession(
        InHomeFrame(backend, origin),
        agent,
        agent_config,
        target_known=target_known,
        open_timings=timings,
        sim_backend=backend,
        on_close=on_close,
    )


def open_episode_session(
    *,
    episode: Any,
    goal_rgb: np.ndarray,
    max_steps: int,
    agent_config_path: Path | None,
    worlds: WorldCache | None = None,
    realism: Realism | None = None,
    memory: HomeSlot | None = None,
    on_close: Callable[[], None] | None = None,
) -> SimSession:
    """A stored episode (its home at full size, its start, target and viewpoints) with the uploaded photo."""
    from sim.backend import SimBackend
    from sim.camera import SIM_CAMERA
    from sim.world import SimWorld

    t0 = time.perf_counter()
    seed = episode.scene_seed
    key = ("episode", seed)
    extra: dict[str, Any] = {}
    if worlds is None:
        world, owns = SimWorld.from_seed(seed), True
    else:
        world, owns = worlds.get(key, lambda: SimWorld.from_seed(seed)), False
        extra["start_render"] = kept_start_render(worlds, key, world, episode.start_pose_world, SIM_CAMERA)
    return _session(
        t0,
        world,
        owns,
        lambda: SimBackend.for_episode(
            world,
            episode,
            goal_rgb,
            max_steps=max_steps,
            owns_world=owns,
            camera=SIM_CAMERA,
            realism=realism,
            **extra,
        ),
        agent_config_path,
        target_known=True,
        memory=memory,
        start_world=Pose2D(*episode.start_pose_world.as_tuple()),
        on_close=on_close,
    )
