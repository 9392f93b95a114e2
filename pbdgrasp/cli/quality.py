"""``pbdgrasp quality``: close the hand at a configuration (autograsp) and print its epsilon quality."""

from __future__ import annotations

import json
import logging

import numpy as np

from assets.errors import InputError
from assets.q_layout import JOINTS

from ._args import float_in, int_in, output_file
from ._out import warn

NAME = "quality"
HELP = "close the hand at Q.json until contact, print epsilon (L1), the contacts and the closed q"
ORDER = 30

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    p.add_argument(
        "--scene", help="scene name or YAML (with --from-db default: the trial's scene, the database row)"
    )
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--q", help="hand configuration Q.json ({'q': [19 numbers]} or named)")
    which.add_argument(
        "--from-db", metavar="RESULTS.sqlite", help="a trial's stored grasp (with --trial; see plan -o)"
    )
    p.add_argument("--trial", type=int_in(0, 10_000), help="with --from-db: the trial number")
    p.add_argument("--row", help="with --from-db: the database row (scene) when it holds several")
    p.add_argument("--planner", help="with --from-db: the planner when the row holds several")
    p.add_argument(
        "--step-deg", type=float_in(0.05, 20.0, "deg"), default=2.0, help="closing step per joint (default 2)"
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--view", choices=["side", "top", "both"], default="both")
    p.add_argument(
        "-o", "--output", type=output_file(".png"), metavar="OUT.png", help="render the closed grasp"
    )


def run(args) -> int:
    from assets import sah
    from assets.io import atomic_write
    from pbdgrasp.cli.render import png_bytes
    from planning.autograsp import AutoGraspConfig, HandCloser
    from planning.qfile import load_q
    from planning.world import World

    step = np.deg2rad(args.step_deg)
    config = AutoGraspConfig(step_rad=step, min_step_rad=min(step, np.deg2rad(0.125)))
    if args.from_db:
        scene, q = _stored_q(args)
    else:
        if args.scene is None:
            raise InputError("--scene: expected a scene (required with --q)")
        scene, q = args.scene, load_q(args.q, hand="sah")
    with World(scene, hand="sah") as world:
        res = HandCloser(world, config).close(q)
        if args.json:
            print(json.dumps(_as_dict(res, sah.JOINT_NAMES), indent=2))
        else:
            print(_as_text(res, sah.JOINT_NAMES))
        if args.output:
            views = ["side", "top"] if args.view == "both" else [args.view]
            image = np.concatenate([world.render(res.closed_q, camera=v) for v in views], axis=1)
            atomic_write(args.output, lambda f: f.write(png_bytes(image)))
            log.info("wrote %s", args.output)
    return 0


def _stored_q(args) -> tuple[str, np.ndarray]:
    """The scene and the pre-closing q of a stored trial (``--from-db``, ``--trial``, ``--row``,
    ``--planner``)."""
    from pbdgrasp.results_db import find_trial
    from planning.qfile import q_from_dict

    if args.trial is None:
        raise InputError("--from-db: expected --trial N as well")
    rec = find_trial(args.from_db, args.trial, args.row, args.planner)
    grasp = json.loads(rec.grasp_json)
    q = grasp.get("q", grasp.get("closed_q"))
    if q is None:
        raise InputError(f"trial {args.trial} ({rec.row}, {rec.planner}) stored no grasp", args.from_db)
    if "q" not in grasp:
        warn(f"trial {args.trial} was not solved: closing its best closed grasp again")
    return args.scene or rec.row, q_from_dict({"q": q}, "sah", args.from_db)


def _as_dict(res, joint_names) -> dict:
    return {
        "epsilon": res.quality,
        "in_collision": res.in_collision,
        "message": res.message,
        "contacts": [
            {"link": link, "point_world_m": p.tolist(), "normal_into_object": n.tolist()}
            for link, p, n in zip(
                res.contact_links, res.contact_points_world, res.contact_normals_world, strict=True
            )
        ],
        "closed_q": res.closed_q.tolist(),
        "closed_joints_deg": dict(
            zip(joint_names, np.rad2deg(res.closed_q[JOINTS]).round(3).tolist(), strict=True)
        ),
        "steps": res.steps,
        "time_ms": 1e3 * res.time_s,
    }


def _as_text(res, joint_names) -> str:
    lines = [f"epsilon (L1): {res.quality:.4f}  ({res.message})"]
    if res.in_collision:
        lines.append("the configuration is in collision before closing: phi_o = 0")
    contacts = zip(res.contact_links, res.contact_points_world, res.contact_normals_world, strict=True)
    for link, p, n in contacts:
        lines.append(
            f"  contact {link:16s} p_world [m] {np.array2string(p, precision=4)}  "
            f"n_into_object {np.array2string(n, precision=3)}"
        )
    lines.append("closed q: " + json.dumps([round(float(x), 6) for x in res.closed_q]))
    joints = ", ".join(
        f"{n} {v:.1f}" for n, v in zip(joint_names, np.rad2deg(res.closed_q[JOINTS]), strict=True)
    )
    lines.append(f"closed joints [deg]: {joints}")
    lines.append(f"{res.steps} closing steps in {1e3 * res.time_s:.1f} ms")
    return "\n".join(lines)
