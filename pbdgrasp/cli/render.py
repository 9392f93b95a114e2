"""``pbdgrasp render``: an offscreen picture of a scene with the hand (pybullet TinyRenderer)."""

from __future__ import annotations

import io
import logging

import numpy as np

from assets.errors import InputError
from assets.io import atomic_write
from assets.q_layout import POS, ROT

from ._args import int_in, output_file

NAME = "render"
HELP = "render a scene with the hand at a configuration to a PNG"
ORDER = 20

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    p.add_argument("--scene", required=True, help="scene name (pbdgrasp assets) or path to a scene YAML")
    p.add_argument("--q", help="hand configuration Q.json (default: open hand hovering above the object)")
    p.add_argument("--hand", default="sah", help="hand model (default sah)")
    p.add_argument("--view", choices=["side", "top", "both"], default="side")
    p.add_argument("--width", type=int_in(16, 4096, "pixels"), default=640, help="pixels (default 640)")
    p.add_argument("--height", type=int_in(16, 4096, "pixels"), default=480, help="pixels (default 480)")
    p.add_argument("-o", "--output", required=True, type=output_file(".png"), metavar="OUT.png")
    p.add_argument(
        "--demo", help="show a human demonstration (name or .npz) on its object; implies --hand human"
    )
    p.add_argument(
        "--steps", default="0,-1", help="with --demo: comma-separated steps to show (default 0,-1)"
    )


def hover_q(world) -> np.ndarray:
    """An open hand pointing down, 5 cm above the top of the object (raised until collision-free)."""
    from planning._pybullet import pb

    lo, hi = pb.getAABB(world.object_id, physicsClientId=world.client)
    q = world.rest_q()
    q[POS] = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2] + 0.05 + reach_m(world)]
    q[ROT] = [np.pi, 0.0, 0.0]  # wrist z (towards the fingers) pointing down
    for _ in range(40):
        if world.is_free(q):
            return q
        q[2] += 0.02
    log.warning("no collision-free hover configuration found; rendering the last one tried")
    return q


def reach_m(world) -> float:
    """Distance [m] from the wrist to the farthest point of the open hand along the wrist z axis."""
    from planning._pybullet import pb

    q = world.rest_q()
    q[2] = 3.0
    world.set_q(q)
    tops = [
        pb.getAABB(world.hand_id, world.link_index(name), physicsClientId=world.client)[1][2]
        for name in (world.base_name, *world.link_names)
    ]
    return max(tops) - 3.0


def png_bytes(rgb: np.ndarray) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    plt.imsave(buf, rgb, format="png")
    return buf.getvalue()


def run(args) -> int:
    from planning.qfile import load_q
    from planning.world import World

    if args.demo:
        return _run_demo(args)
    with World(args.scene, hand=args.hand) as world:
        q = load_q(args.q, hand=args.hand) if args.q else hover_q(world)
        views = ["side", "top"] if args.view == "both" else [args.view]
        images = [world.render(q, args.width, args.height, camera=v) for v in views]
        free = world.is_free(q)
    rgb = np.concatenate(images, axis=1)
    atomic_write(args.output, lambda f: f.write(png_bytes(rgb)))
    print(f"wrote {args.output} ({rgb.shape[1]} x {rgb.shape[0]}); hand {'free' if free else 'IN COLLISION'}")
    return 0


def _run_demo(args) -> int:
    """Render a demonstration's human hand (the recorded, noisy poses) at the chosen steps, side by side."""
    from assets.se3 import q_from_pose
    from planning.world import World
    from retarget.demonstration import Demonstration

    demo = Demonstration.load(args.demo)
    try:
        steps = [int(s) for s in args.steps.split(",") if s.strip()]
    except ValueError:
        raise InputError(f"--steps: expected comma-separated integers, found {args.steps!r}") from None
    if not steps or any(not -demo.num_steps <= s < demo.num_steps for s in steps):
        raise InputError(
            f"--steps: expected steps in [-{demo.num_steps}, {demo.num_steps - 1}], found {steps}"
        )
    images = []
    with World(args.scene, hand="human") as world:
        if world.scene.object.name != demo.object:
            raise InputError(
                f"--demo {demo.object} is on another object than the scene's {world.scene.object.name}"
            )
        for step in steps:
            T_world_wrist = world.scene.T_world_object @ demo.T_object_wrist[step]
            q = np.concatenate([q_from_pose(T_world_wrist), demo.joints[step]])
            images.append(
                world.render(q, args.width, args.height, camera=args.view if args.view != "both" else "side")
            )
    rgb = np.concatenate(images, axis=1)
    atomic_write(args.output, lambda f: f.write(png_bytes(rgb)))
    print(f"wrote {args.output}: demonstration {demo.object} at steps {steps}")
    return 0
