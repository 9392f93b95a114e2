"""``pbdgrasp inspect MODEL --scene S [--draws 300] [--json] [--plot out.png]``: where a strategy fails in a
scene, before planning (:mod:`pbdgrasp.inspect`)."""

from __future__ import annotations

import logging

import numpy as np

from assets.errors import InputError

NAME = "inspect"
HELP = "per time step, the fraction of collision-free draws of a model in a scene; the last step's grasps"
ORDER = 45

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL", help="variation model (.model.npz)")
    p.add_argument("--scene", required=True, help="scene name or YAML file")
    p.add_argument("--draws", type=int, default=300, help="draws per time step (default 300)")
    p.add_argument("--epsilon", type=float, default=0.05, help="quality of a valid grasp (default 0.05)")
    p.add_argument("--seed", type=int, default=0, help="seed of the draws (default 0)")
    p.add_argument("--json", action="store_true", help="print the measurements as JSON")
    p.add_argument("--plot", metavar="OUT.png", help="also plot the collision-free fraction over time")


def run(args) -> int:
    from inference.model import VariationModel
    from pbdgrasp.inspect import inspect_model, plot_free_fraction
    from planning.scene import load_scene

    if args.draws < 1 or args.draws > 100_000:
        raise InputError(f"--draws: expected 1..100000, found {args.draws}")
    if args.seed < 0:
        raise InputError(f"--seed: expected an integer >= 0, found {args.seed}")
    model = VariationModel.load(args.model)
    scene = load_scene(args.scene)
    if model.object != scene.object.name:
        log.warning("the model was learned on %r, the scene's object is %r", model.object, scene.object.name)
    result = inspect_model(model, scene, args.draws, np.random.default_rng(args.seed), args.epsilon)
    print(result.to_json() if args.json else result.summary())
    if args.plot:
        plot_free_fraction({f"{scene.name} ({model.object})": result}, args.plot)
    return 0
