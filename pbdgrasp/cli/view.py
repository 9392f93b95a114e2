"""``pbdgrasp view``: look at strategies in a scene in 3-D (a viser server on 127.0.0.1; any browser).

The scene, the SAH at a strategy's mean with a step slider, the fingertips' 1-sigma ellipsoids, draws of a
step as translucent hands (green collision-free, red not), and a stored trial's path and closed grasp with
its contacts, normals and epsilon. It prints the address and serves until Ctrl-C; ``--screenshot OUT.png``
renders one picture in headless Chromium and exits.
"""

from __future__ import annotations

import logging
import signal
import threading
from pathlib import Path

import numpy as np

from assets.errors import InputError
from pbdgrasp.viewer import LAYERS

from ._args import int_in, output_file, seed
from ._out import stage, warn

NAME = "view"
HELP = "serve a 3-D view of a scene, strategies' marginals and a planned trial (viser, a browser)"
ORDER = 45

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    p.add_argument("--scene", required=True, help="scene name (pbdgrasp assets) or path to a scene YAML")
    p.add_argument("--model", action="append", default=[], metavar="M.model.npz", help="a model (repeatable)")
    p.add_argument(
        "--results", metavar="R.sqlite", help="a results database (plan -o, table1) to show a trial of"
    )
    p.add_argument(
        "--trial", type=int_in(0, 10_000), help="with --results: the trial (default: the best solved one)"
    )
    p.add_argument("--planner", help="with --results: the planner when the database holds several")
    p.add_argument(
        "--step", type=int, help="the time step shown first (default: the last; negative from the end)"
    )
    p.add_argument(
        "--draws", type=int_in(0, 200), default=0, help="draw N hands of that step at start (default 0)"
    )
    p.add_argument(
        "--port", type=int_in(0, 65535), default=8080, help="port on 127.0.0.1 (default 8080; 0: a free one)"
    )
    p.add_argument(
        "--screenshot",
        type=output_file(".png"),
        metavar="OUT.png",
        help="render once in headless Chromium, exit",
    )
    p.add_argument("--view", choices=["side", "top"], default="side", help="with --screenshot: the camera")
    p.add_argument(
        "--width", type=int_in(64, 4096, "pixels"), default=1280, help="with --screenshot (default 1280)"
    )
    p.add_argument(
        "--height", type=int_in(64, 4096, "pixels"), default=800, help="with --screenshot (default 800)"
    )
    p.add_argument(
        "--hide",
        default="",
        metavar="LAYERS",
        help="comma-separated layers to hide at start: " + ", ".join(LAYERS),
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the draws")


def _trial(args, row: str):
    """The trial to show: ``--trial`` or the best solved trial of the scene's row."""
    from pbdgrasp.results_db import find_trial, load_trials, open_db

    if args.trial is not None:
        return find_trial(args.results, args.trial, row, args.planner)
    conn = open_db(args.results, create=False)
    try:
        records = [r for r in load_trials(conn, rows=[row]) if args.planner in (None, r.planner)]
    finally:
        conn.close()
    solved = [r for r in records if r.success]
    if not solved:
        raise InputError(f"no solved trial of row {row!r} is stored; choose one with --trial", args.results)
    return max(solved, key=lambda r: (r.quality, -r.trial))


def run(args) -> int:
    from assets.io import atomic_write
    from inference.model import VariationModel
    from pbdgrasp.cli.render import png_bytes
    from pbdgrasp.viewer.app import StrategyViewer, trial_path
    from pbdgrasp.viewer.browser import find_chromium, screenshot
    from planning.scene import load_scene

    if args.screenshot:
        find_chromium()  # before any work
    import rich

    rich.get_console().quiet = True  # viser's banner and "Server stopped": the address is printed below
    scene = load_scene(args.scene)
    models = {}
    for path in args.model:
        label = Path(path).name.removesuffix(".npz").removesuffix(".model")
        if label in models:
            raise InputError(f"--model: two models are named {label!r}", path)
        models[label] = VariationModel.load(path)
        if models[label].object != scene.object.name:
            warn(
                f"{path} was learned on {models[label].object!r}; the scene's object is {scene.object.name!r}"
            )
    if args.trial is not None and args.results is None:
        raise InputError("--trial: expected --results R.sqlite as well")
    trial = _trial(args, scene.name) if args.results else None
    if trial is not None and not len(trial_path(trial)):
        warn(f"trial {trial.trial} stored no path (not solved, or planned before paths were stored)")
    hide = [name for name in args.hide.split(",") if name]
    for name in hide:
        if name not in LAYERS:
            raise InputError(f"--hide: expected layers among {', '.join(LAYERS)}, found {name!r}")
    if models:
        label = next(iter(models))
        T = models[label].num_steps
        k = T - 1 if args.step is None else args.step
        k = k + T if k < 0 else k
        if not 0 <= k < T:
            raise InputError(f"--step: expected -{T}..{T - 1} for {label} ({T} steps), found {args.step}")
    stage(f"building the view of {scene.name}")
    viewer = StrategyViewer(scene, models, trial, np.random.default_rng(args.seed), port=args.port)
    try:
        for name in hide:
            viewer.set_visible(name, False)
        if models:
            viewer.show_step(label, k)
            if args.draws:
                free = viewer.draw_samples(args.draws)
                print(f"step {k}: {int(free.sum())} of {len(free)} draws collision-free")
        if args.screenshot:
            image = screenshot(
                viewer.server, lambda c: viewer.look_from(c, args.view), args.width, args.height
            )
            atomic_write(args.screenshot, lambda f: f.write(png_bytes(image)))
            print(f"wrote {args.screenshot}")
            return 0
        print(f"pbdgrasp view: open {viewer.url} in a browser (Ctrl-C to stop)", flush=True)
        _wait_for_interrupt()
        return 0
    finally:
        viewer.close()


def _wait_for_interrupt() -> None:
    done = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        while not done.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
