"""``pbdgrasp quality``: close the hand at a configuration (autograsp) and print its epsilon quality."""

from __future__ import annotations

import json
import logging

import numpy as np

from assets.errors import InputError
from assets.q_layout import JOINTS

NAME = "quality"
HELP = "close the hand at Q.json until contact, print epsilon (L1), the contacts and the closed q"
ORDER = 30

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    p.add_argument("--scene", required=True, help="scene name (pbdgrasp assets) or path to a scene YAML")
    p.add_argument("--q", required=True, help="hand configuration Q.json ({'q': [19 numbers]} or named)")
    p.add_argument("--step-deg", type=float, default=2.0, help="closing step per joint [deg] (default 2)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--view", choices=["side", "top", "both"], default="both")
    p.add_argument("-o", "--output", help="render the closed grasp to this PNG")


def run(args) -> int:
    from assets import sah
    from assets.io import atomic_write
    from pbdgrasp.cli.render import png_bytes
    from planning.autograsp import AutoGraspConfig, HandCloser
    from planning.qfile import load_q
    from planning.world import World

    if not (0.05 <= args.step_deg <= 20.0):
        raise InputError(f"--step-deg: expected 0.05..20 deg, found {args.step_deg}")
    step = np.deg2rad(args.step_deg)
    config = AutoGraspConfig(step_rad=step, min_step_rad=min(step, np.deg2rad(0.125)))
    with World(args.scene, hand="sah") as world:
        q = load_q(args.q, hand="sah")
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
