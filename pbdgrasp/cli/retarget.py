"""``pbdgrasp retarget``: a human demonstration to the SAH trajectory tau_r and Sigma_r(t) (paper, IV).

The collision term d6 checks the SAH against the object and the table of the object's obstacle-free
scene (the shipped scene named like the object, e.g. ``ham``), in pybullet.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from assets.errors import InputError
from retarget.config import FINAL_GRASPS, TARGETS

from ._args import add_processes_argument, float_in, int_in, output_file, seed

NAME = "retarget"
HELP = "retarget a human demonstration to the SAH: write tau_r and Sigma_r(t) (.traj.npz)"
ORDER = 30

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    p.add_argument("demo", metavar="DEMO", help="demonstration name (ham, jam, ...) or path to a .npz file")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        type=output_file(".traj.npz"),
        metavar="TRAJ",
        help="output .traj.npz",
    )
    p.add_argument(
        "--seed", type=seed, default=0, help="the seed of the refined final grasp's draws (and provenance)"
    )
    p.add_argument("--scene", help="scene for the collision check (default: the scene named like the object)")
    p.add_argument("--no-collision", action="store_true", help="drop d6 (no collision check; faster)")
    p.add_argument(
        "--max-nfev", type=int_in(1, 100_000), default=None, help="Rosenbrock evaluations per step"
    )
    p.add_argument(
        "--targets",
        choices=TARGETS,
        default="by_grasp_type",
        help="fingertip targets: the paper's human fingertips, or scaled from the palm by the hand-size "
        "ratio (default by_grasp_type: scaled for power grasps)",
    )
    p.add_argument(
        "--scaled-wrist-weight",
        type=float_in(0.0, 1e4),
        default=None,
        metavar="W5",
        help="w5 of the wrist distance where the targets are scaled (default by strategy: 3 for salt, "
        "the paper's 0.1 for the others; docs/method.md)",
    )
    add_final_grasp_argument(p)
    add_processes_argument(p)
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def add_final_grasp_argument(p) -> None:
    """``--final-grasp``, shared with ``learn``."""
    p.add_argument(
        "--final-grasp",
        choices=FINAL_GRASPS,
        default="by_grasp_type",
        help="the last step: the fingertip search's (paper), or searched again near it for the "
        "configuration whose draws close to the best grasps (refined; needs the collision check's scene); "
        "default by_grasp_type: refined for precision grasps, paper for power grasps",
    )


def config_of(args, **settings):
    """The :class:`~retarget.retargeting.RetargetConfig` of the command line's options."""
    from retarget.final_grasp import FinalGraspConfig
    from retarget.retargeting import RetargetConfig

    if args.max_nfev is not None:
        settings["max_nfev"] = args.max_nfev
    if getattr(args, "scaled_wrist_weight", None) is not None:
        settings["scaled_wrist_weight"] = args.scaled_wrist_weight
    return RetargetConfig(
        final_grasp=args.final_grasp, final_grasp_settings=FinalGraspConfig(seed=args.seed), **settings
    )


def run(args) -> int:
    from pbdgrasp.strategy import retarget_in_scene
    from planning.scene import load_scene
    from retarget.demonstration import Demonstration

    out = Path(args.output)
    demo = Demonstration.load(args.demo)
    config = config_of(args, targets=args.targets)
    scene = None
    if not args.no_collision:
        scene = load_scene(args.scene or demo.object)
        if scene.object.name != demo.object:
            raise InputError(
                f"--scene: scene {scene.name!r} holds {scene.object.name!r}, "
                f"the demonstration {demo.object!r}"
            )
    start = time.perf_counter()
    traj, result = retarget_in_scene(
        demo, scene, config, progress=not args.no_progress, meta={"seed": args.seed}, processes=args.processes
    )
    traj.save(out)
    print(summary(demo, traj, result, time.perf_counter() - start, out))
    return 0


def summary(demo, traj, result, elapsed_s: float, out) -> str:
    """The one line a retargeting prints: the fit, how the last step holds the object, the time."""
    collide = result.meta.get("steps_in_collision")
    shape = result.meta.get("last_step")
    held = (
        f"last step: palm {shape['palm_to_object_mm']:.0f} mm from the object, "
        f"{shape['contact_links']} links touching; "
        if shape
        else ""
    )
    final = result.meta.get("final_grasp")
    refined = (
        f"final grasp refined: draws' mean epsilon {final['expected_quality_before']:.3f} -> "
        f"{final['expected_quality_after']:.3f}; "
        if final
        else ""
    )
    return (
        f"{demo.object} ({demo.grasp_type}): {traj.num_steps} steps, fingertip RMSE {result.rmse_mm:.1f} mm "
        f"(final step {result.fingertip_rmse_mm[-1]:.1f} mm, targets {result.meta['targets']}), "
        f"{held}{refined}"
        f"{result.virtual_fingers.describe() if result.virtual_fingers else ''}, "
        f"steps in collision {'n/a' if collide is None else collide}, {elapsed_s:.1f} s -> {out}"
    )
