"""``pbdgrasp infer TRAJ [--scene S] [--params P.yaml] -o MODEL.model.npz``: the variation model (paper V-VI).

Without ``--scene`` the object prior is the trajectory's and the only constraints are the SAH's joint
limits. With it, the object prior is the scene's object pose and localization covariance, and every step
gets a clearance factor: the SAH's sphere cover against the distance fields of the scene's table,
obstacles and object and against itself (:mod:`pbdgrasp.scene_model`, :mod:`inference.solve`).
"""

from __future__ import annotations

import time

from assets.sah import JOINT_LIMITS
from inference import VariationParams, solve
from retarget.trajectory import Trajectory

from ._args import output_file
from ._out import stage, warn

NAME = "infer"
HELP = "learn the variation model (marginals P(X_t | O)) from a retargeted trajectory"
ORDER = 40


def add_arguments(p) -> None:
    p.add_argument("trajectory", metavar="TRAJ", help="retargeted trajectory (.traj.npz)")
    p.add_argument("--scene", help="scene name or YAML file: object prior and constraint factors")
    p.add_argument("--params", metavar="P.yaml", help="parameter file (see inference/params.py)")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        type=output_file(".model.npz"),
        metavar="MODEL.model.npz",
        help="model file to write",
    )
    add_scene_grasp_argument(p)
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def add_scene_grasp_argument(p) -> None:
    """``--no-scene-grasp`` (infer, learn)."""
    p.add_argument(
        "--no-scene-grasp",
        action="store_true",
        help="keep the final grasp the model solves to in the scene (default: choose it again there, "
        "pbdgrasp.scene_grasp, as Table I does)",
    )


def run(args) -> int:
    start = time.perf_counter()
    traj = Trajectory.load(args.trajectory)
    params = VariationParams.from_yaml(args.params) if args.params else VariationParams()
    scene = None
    if args.scene:
        from planning.scene import load_scene

        scene = load_scene(args.scene)
        if scene.object.name != traj.object:
            warn(
                f"{args.trajectory} is a strategy for {traj.object!r}; the scene holds {scene.object.name!r}"
            )
    model = infer(traj, scene, params, no_progress=args.no_progress, scene_grasp=not args.no_scene_grasp)
    model.save(args.output)
    print(summary(model, args.output, time.perf_counter() - start))
    return 0


def infer(traj, scene, params, no_progress: bool = False, scene_grasp: bool = True):
    """The variation model of ``traj``: in ``scene`` (its object prior and clearance factors) or, with
    ``scene=None``, with the joint limits only; a progress bar of the solver's iterations. With
    ``scene_grasp`` and a scene, the final grasp is chosen again there
    (:func:`pbdgrasp.scene_grasp.adapt_final_grasp`)."""
    from tqdm import tqdm

    bar = tqdm(desc="solving the variation model", unit="it", disable=no_progress or None, leave=False)

    def tick(error: float) -> None:
        bar.update(1)
        bar.set_postfix(error=f"{error:.4g}")

    try:
        if scene is None:
            return solve(traj, params, joint_limits=JOINT_LIMITS, on_iteration=tick)
        from pbdgrasp.scene_model import learn_in_scene

        stage(
            f"scene {scene.name}: distance fields and the clearance factors",
            enabled=False if no_progress else None,
        )
        model = learn_in_scene(traj, scene, params, on_iteration=tick)
    finally:
        bar.close()
    from pbdgrasp.scene_grasp import adapt_final_grasp

    if scene_grasp:
        stage(f"scene {scene.name}: choosing the final grasp again", enabled=False if no_progress else None)
        model = adapt_final_grasp(model, scene, params)
        print(scene_grasp_line(model.source.meta["scene_grasp"], scene.name))
    return model


def scene_grasp_line(found: dict, scene_name: str) -> str:
    """The line that says what choosing the final grasp again in a scene did (``meta["scene_grasp"]``)."""
    before = found["before"]
    kept = next((t for t in found["tried"] if t["candidate"] == found.get("candidate")), None)
    after = f"; with it {kept['valid_fraction']:.0%}, {kept['least_free_fraction']:.0%}" if kept else ""
    return (
        f"final grasp in {scene_name}: {'chosen again' if kept else 'kept as solved'} "
        f"({len(found['tried'])} candidate(s) solved again; last-step valid, least free: "
        f"{before['valid_fraction']:.0%}, {before['least_free_fraction']:.0%}{after})"
    )


def summary(model, out, elapsed_s: float) -> str:
    """The one line an inference prints: steps, constraints, iterations and convergence, times."""
    status = "converged" if model.converged else "NOT converged"
    return (
        f"{out}: T = {model.num_steps}, {int(model.constrained.sum())} constrained steps, "
        f"{model.iterations} iteration(s) {status}, solve {model.solve_time_s * 1e3:.0f} ms, "
        f"total {elapsed_s * 1e3:.0f} ms"
    )
