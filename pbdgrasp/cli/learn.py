"""``pbdgrasp learn DEMO [--scene S] -o M.model.npz``: a strategy from a demonstration in one command.

``retarget`` (paper IV, d6 checked in the object's obstacle-free scene) then ``infer`` in ``--scene`` (V-VI;
default that same scene), with both commands' defaults; ``--trajectory T.traj.npz`` keeps tau_r as well.
The two stages separately, with all their options: ``pbdgrasp retarget`` and ``pbdgrasp infer``.
"""

from __future__ import annotations

import time

from ._args import add_processes_argument, int_in, output_file, seed
from ._out import stage, warn
from .infer import add_scene_grasp_argument
from .retarget import add_final_grasp_argument

NAME = "learn"
HELP = "a strategy from a demonstration: retarget it, then infer the variation model in a scene"
ORDER = 41


def add_arguments(p) -> None:
    p.add_argument("demo", metavar="DEMO", help="demonstration name (ham, jam, ...) or path to a .npz file")
    p.add_argument("--scene", help="scene of the variation model (default: the scene named like the object)")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        type=output_file(".model.npz"),
        metavar="M.model.npz",
        help="the model",
    )
    p.add_argument(
        "--trajectory", type=output_file(".traj.npz"), metavar="T.traj.npz", help="also keep the trajectory"
    )
    p.add_argument(
        "--max-nfev", type=int_in(1, 100_000), default=None, help="Rosenbrock evaluations per step"
    )
    p.add_argument(
        "--seed", type=seed, default=0, help="the seed of the refined final grasp's draws (and provenance)"
    )
    add_final_grasp_argument(p)
    add_scene_grasp_argument(p)
    add_processes_argument(p)
    p.add_argument("--no-progress", action="store_true", help="hide the progress bars")


def run(args) -> int:
    from inference import VariationParams
    from pbdgrasp.strategy import retarget_in_scene
    from planning.scene import load_scene
    from retarget.demonstration import Demonstration

    from . import infer, retarget

    start = time.perf_counter()
    demo = Demonstration.load(args.demo)
    own_scene = load_scene(demo.object)
    scene = load_scene(args.scene) if args.scene else own_scene
    if scene.object.name != demo.object:
        warn(f"{args.demo} demonstrates {demo.object!r}; the scene holds {scene.object.name!r}")
    config = retarget.config_of(args)
    stage(f"retargeting {demo.object} ({demo.num_steps} steps)", enabled=False if args.no_progress else None)
    traj, result = retarget_in_scene(
        demo,
        own_scene,
        config,
        progress=not args.no_progress,
        meta={"seed": args.seed},
        processes=args.processes,
    )
    if args.trajectory:
        traj.save(args.trajectory)
    print(retarget.summary(demo, traj, result, time.perf_counter() - start, args.trajectory or "(not kept)"))
    start = time.perf_counter()
    model = infer.infer(
        traj, scene, VariationParams(), no_progress=args.no_progress, scene_grasp=not args.no_scene_grasp
    )
    model.save(args.output)
    print(infer.summary(model, args.output, time.perf_counter() - start))
    return 0
