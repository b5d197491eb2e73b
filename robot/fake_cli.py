"""``imgnav fake-stretch``: serve a simulated Stretch that speaks the stretch_ai bridge protocol.

Rehearse a robot run on one machine::

    imgnav fake-stretch --scene-seed 3              # a PyBullet home, random free start
    imgnav fake-stretch --scene-seed 0 --rooms 3    # the console's simulator home-0
    imgnav fake-stretch --episodes data/episodes/val --episode val-0007
    imgnav fake-stretch --world box                 # an empty analytic room (no PyBullet)

then point the console (or any stretch_ai client) at 127.0.0.1. Faults for rehearsal:
``--runstopped``, ``--not-homed``, ``--drop-acks``, ``--silent-after-s``, ``--slow``. Observations
follow the bridge's order by default (``--idealised`` turns that off).
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading

from agent.types import VIEWPOINT_SUCCESS_RADIUS_M, Pose2D
from robot.fake_server import FakeKnobs, FakeStretch
from robot.protocol import ACTION_PORT, OBS_PORT, STATE_PORT

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_argument_group("world")
    where.add_argument(
        "--world", choices=("sim", "box"), default="sim", help="PyBullet home (default) or an empty box room"
    )
    where.add_argument("--scene-seed", type=int, default=0, help="home to generate (with --world sim)")
    where.add_argument("--rooms", type=int, help="rooms of the generated home (the console's simulator homes have 3)")
    where.add_argument("--episodes", help="episode set directory: start where an episode starts")
    where.add_argument("--episode", help="episode id within --episodes")
    where.add_argument(
        "--start", type=float, nargs=3, metavar=("X", "Y", "YAW"), help="start pose in the home frame (m, m, rad)"
    )
    net = parser.add_argument_group("network")
    net.add_argument("--host", default="127.0.0.1", help="address to bind (default loopback)")
    net.add_argument("--obs-port", type=int, default=OBS_PORT)
    net.add_argument("--action-port", type=int, default=ACTION_PORT)
    net.add_argument("--state-port", type=int, default=STATE_PORT)
    faults = parser.add_argument_group("faults")
    faults.add_argument("--runstopped", action="store_true", help="report the runstop pressed (motion frozen)")
    faults.add_argument("--not-homed", action="store_true", help="report the robot not homed")
    faults.add_argument("--drop-acks", action="store_true", help="execute actions but never echo their steps")
    faults.add_argument("--silent-after-s", type=float, help="stop publishing this many seconds after start")
    faults.add_argument("--slow", action="store_true", help="move at a real Stretch's pace (0.2 m/s, 0.6 rad/s)")
    faults.add_argument(
        "--idealised",
        action="store_true",
        help="build each observation at one instant instead of in the bridge's order (images, pose, "
        "compression, then the step at send time, so an observation echoing a step can predate its motion's end)",
    )
    faults.add_argument(
        "--nonblocking-nav",
        action="store_true",
        help="acknowledge a goal at once and move afterwards, at_goal false until the base arrives "
        "(as stretch_ai's MuJoCo server)",
    )
    faults.add_argument(
        "--never-arrive",
        action="store_true",
        help="with --nonblocking-nav: every motion stalls halfway and at_goal never turns true",
    )


def build_world(args: argparse.Namespace):
    start = Pose2D(*args.start) if args.start else None
    if args.world == "box":
        from robot.fake_world import BoxWorld

        return BoxWorld(start_world=start or Pose2D(0.0, 0.0, 0.0))
    from robot.fake_sim import SimFakeWorld

    if args.episodes:
        if not args.episode:
            raise SystemExit("--episodes needs --episode")
        return SimFakeWorld.from_episode(args.episodes, args.episode)
    return SimFakeWorld.from_seed(args.scene_seed, start_world=start, n_rooms=args.rooms)


def run(args: argparse.Namespace) -> int:
    if args.never_arrive and not args.nonblocking_nav:
        raise SystemExit("--never-arrive needs --nonblocking-nav (a blocking robot would never acknowledge)")
    knobs = FakeKnobs(
        runstopped=args.runstopped,
        homed=not args.not_homed,
        drop_acks=args.drop_acks,
        faithful=not args.idealised,
        nonblocking_nav=args.nonblocking_nav,
        never_arrive=args.never_arrive,
    )
    if args.slow:
        knobs.linear_speed_m_s, knobs.angular_speed_rad_s = 0.2, 0.6
    world = build_world(args)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    fake = FakeStretch(
        world,
        host=args.host,
        obs_port=args.obs_port,
        action_port=args.action_port,
        state_port=args.state_port,
        knobs=knobs,
    ).start()
    assert fake.ports is not None  # bound by start()
    obs_port, action_port, state_port = fake.ports
    try:
        print(
            f"fake Stretch at {args.host}: observations {obs_port}, actions {action_port}, "
            f"state {state_port}; start {world.start_world}. Ctrl-C to stop.",
            flush=True,
        )
        goal_image = getattr(world, "goal_image_path", None)
        if goal_image is not None:
            print(f"the episode's goal image (upload it as the goal photo): {goal_image}", flush=True)
        if args.silent_after_s is not None and not stop.wait(args.silent_after_s):
            knobs.silent = True
            log.warning("fake Stretch: silent from now on (--silent-after-s)")
        last_step = fake.handled_step
        while not stop.wait(1.0):
            if fake.handled_step != last_step:  # a line per second of activity, none when idle
                last_step = fake.handled_step
                log.info("fake Stretch: step %d, pose %s", last_step, fake.pose_world)
    finally:
        fake.close()
        distance = getattr(world, "distance_to_goal_m", lambda pose: None)(fake.pose_world)
        if distance is not None:
            verdict = "at" if distance <= VIEWPOINT_SUCCESS_RADIUS_M else "not at"
            print(
                f"final pose {fake.pose_world}: {distance:.2f} m from the nearest goal viewpoint ({verdict} the goal)",
                flush=True,
            )
        world.close()
    return 0
