"""``pbdgrasp inspect MODEL --scene S [--draws 300] [--json] [--plot out.png]``: where a strategy fails in a
scene, before planning (:mod:`pbdgrasp.inspect`)."""

from __future__ import annotations

import logging

import numpy as np

from ._args import add_processes_argument, float_in, int_in, output_file, seed
from ._out import warn

NAME = "inspect"
HELP = "per time step, the fraction of collision-free draws of a model in a scene; the last step's grasps"
ORDER = 45

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL", help="variation model (.model.npz)")
    p.add_argument("--scene", required=True, help="scene name or YAML file")
    p.add_argument("--draws", type=int_in(1, 100_000), default=300, help="draws per time step (default 300)")
    p.add_argument(
        "--epsilon", type=float_in(0.0, 1.0, lo_open=True), default=0.05, help="quality of a valid grasp"
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the draws (default 0)")
    p.add_argument("--json", action="store_true", help="print the measurements as JSON")
    add_processes_argument(p)
    p.add_argument(
        "--plot", type=output_file(".png"), metavar="OUT.png", help="also plot the free fraction over time"
    )


def run(args) -> int:
    from inference.model import VariationModel
    from pbdgrasp.inspect import inspect_model, plot_free_fraction
    from planning.scene import load_scene

    model = VariationModel.load(args.model)
    scene = load_scene(args.scene)
    if model.object != scene.object.name:
        warn(f"{args.model} was learned on {model.object!r}; the scene's object is {scene.object.name!r}")
    rng = np.random.default_rng(args.seed)
    result = inspect_model(model, scene, args.draws, rng, args.epsilon, args.processes)
    print(result.to_json() if args.json else result.summary())
    if args.plot:
        plot_free_fraction({f"{scene.name} ({model.object})": result}, args.plot)
    return 0
