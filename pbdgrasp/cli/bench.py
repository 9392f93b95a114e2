"""``pbdgrasp bench``: the performance figures of every stage, measured in one process.

Prints a table (the machine first) or, with ``--json``, the full results as JSON on stdout; ``-o`` also
writes the JSON to a file (atomically). See :mod:`pbdgrasp.bench` for what is measured and how.
"""

from __future__ import annotations

import json
import sys

from ._args import float_in, int_in, output_dir, output_file, seed

NAME = "bench"
HELP = "measure inference, sampling, collision, quality, retargeting and planning speed on this machine"
ORDER = 90


def add_arguments(p) -> None:
    p.add_argument("--quick", action="store_true", help="tiny settings (seconds): ham planning only")
    p.add_argument(
        "--trials", type=int_in(1, 1000), default=3, help="planning trials per scene and planner (default 3)"
    )
    p.add_argument(
        "--time-limit-s", type=float_in(0, 3600, "s", lo_open=True), default=10.0, help="budget of one query"
    )
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--json", action="store_true", help="print the results as JSON instead of the table")
    p.add_argument("-o", "--output", type=output_file(".json"), metavar="BENCH.json", help="also write JSON")
    p.add_argument(
        "--cache-dir", type=output_dir, default="results/cache/bench", help="cached strategies (%(default)s)"
    )
    p.add_argument(
        "--retarget-max-nfev",
        type=int_in(1, 100_000),
        default=100,
        help="Rosenbrock evaluations per step (strategies)",
    )

    p.add_argument(
        "--model",
        action="append",
        default=[],
        metavar="SCENE=M.model.npz",
        help="plan SCENE with this strategy instead of building one (repeatable)",
    )


def run(args) -> int:
    from assets.errors import InputError
    from assets.io import atomic_write
    from pbdgrasp.bench import BenchConfig, run_bench

    models = []
    for item in args.model:
        scene, sep, path = item.partition("=")
        if not sep or not scene or not path:
            raise InputError(f"--model: expected SCENE=M.model.npz, found {item!r}")
        models.append((scene, path))
    config = BenchConfig(
        quick=args.quick,
        trials=args.trials,
        seed=args.seed,
        time_limit_s=args.time_limit_s,
        cache_dir=args.cache_dir,
        retarget_max_nfev=args.retarget_max_nfev,
        models=tuple(models),
    )
    results = run_bench(config, progress=lambda name: print(f"bench: {name} ...", file=sys.stderr))
    text = json.dumps(results, indent=2, sort_keys=True)
    if args.output:
        atomic_write(args.output, lambda f: f.write(text.encode() + b"\n"))
    print(text if args.json else format_table(results))
    return 0


def _f(x, fmt: str = ".3g", none: str = "-") -> str:
    return none if x is None else format(x, fmt)


def format_table(r: dict) -> str:
    """The bench results as a plain-text table."""
    m = r["machine"]
    lines = [
        f"machine: {m['cpu_model']}, {m['cpu_count']} CPUs, {m['platform']}, Python {m['python']}, "
        f"GTSAM {m['gtsam']}",
        "",
        "inference (graph + Gauss-Newton + marginals; marginals alone: gtsam vs dense inverse)",
        f"  {'T':>5} {'solve ms':>10} {'marg. ms':>10} {'dense ms':>10} {'dense/gtsam':>12} "
        f"{'max rel diff':>13}",
    ]
    for row in r["inference"]["rows"]:
        lines.append(
            f"  {row['T']:>5} {row['solve_ms']:>10.1f} {row['marginals_ms']:>10.1f} {row['dense_ms']:>10.1f} "
            f"{row['dense_over_gtsam']:>12.2f} {row['max_rel_diff']:>13.1e}"
        )
    lines += [
        "",
        "scene inference (clearance factors, LM, joint limits; the distance fields built apart; then the",
        "final grasp chosen again in the scene: its time, and whether a re-solved model was kept)",
        f"  {'row':<20} {'T':>4} {'solve s':>8} {'fields s':>9} {'LM its':>7} {'converged':>10} "
        f"{'grasp s':>8} {'kept':>5}",
    ]
    for row, c in r["scene_inference"].items():
        lines.append(
            f"  {row:<20} {c['T']:>4} {c['solve_s']:>8.1f} {c['fields_s']:>9.1f} {c['iterations']:>7} "
            f"{'yes' if c['converged'] else 'NO':>10} {c['scene_grasp_s']:>8.1f} "
            f"{'yes' if c['scene_grasp_kept'] else 'no':>5}"
        )
    lines += [
        "",
        f"sampler: {r['sampler']['samples_per_s']:.3g} samples/s from P(Y) (n = {r['sampler']['n']}; numpy "
        f"draws {r['sampler'].get('numpy_normals_19d_per_s', float('nan')):.3g} 19-D normals/s here)",
    ]
    col = r["collision"]
    lines.append(
        f"collision: {col['configs_per_s']:.0f} configurations/s ({col['us_per_config']:.0f} us each, "
        f"{100 * col['free_fraction']:.0f}% free), {col['edges_per_s']:.0f} edges/s "
        f"({col['configs_per_edge']:.1f} configurations per edge)"
    )
    qu = r["quality"]
    lines.append(
        f"quality: epsilon from 4 contacts {qu['epsilon_us']:.0f} us; close-and-score "
        f"{qu['close_and_score_ms']:.1f} ms (ham grasp epsilon {qu['ham_grasp_quality']:.3f}, "
        f"{qu['closing_steps']} steps)"
    )
    rt = r["retargeting"]
    lines.append(
        f"retargeting: {rt['s_per_step']:.2f} s/step, final grasp {rt['final_grasp_s']:.1f} s "
        f"on {rt['closing_processes']} processes "
        f"({rt['total_s']:.1f} s for {rt['steps']} steps of {rt['demonstration']}, "
        f"max_nfev {rt['max_nfev']}, {rt['collision_checks']} collision checks)"
    )
    from pbdgrasp.bench import PLANNING_SCENES

    w = 1 + max(map(len, (*PLANNING_SCENES, *r["planning"])))  # the scene column, one space to spare
    lines += [
        "",
        "planning (per scene and planner; shares of planning time: pybullet collision / quality / overhead)",
        f"  {'scene':<{w}} {'planner':<13} {'success':>8} {'med ETA s':>10} {'nodes':>7} {'checks':>8} "
        f"{'coll.':>6} {'qual.':>6} {'ours':>6}",
    ]
    for scene, s in r["planning"].items():
        for name, p in s["planners"].items():
            lines.append(
                f"  {scene:<{w}} {name:<13} {p['success_rate']:>8.0%} {_f(p['median_eta_s'], '.2f'):>10} "
                f"{p['median_nodes']:>7.0f} {p['median_collision_checks']:>8.0f} "
                f"{_f(p['share_collision'], '.0%'):>6} {_f(p['share_quality'], '.0%'):>6} "
                f"{_f(p['share_overhead'], '.0%'):>6}"
            )
        ra = s["ratios"]
        lines.append(
            f"  {scene:<{w}} median ETA learned/OMPL {_f(ra['learned_over_ompl'], '.2f')}, "
            f"learned/baseline {_f(ra['learned_over_baseline'], '.2f')}"
        )
    lines += ["", f"peak memory: {r['memory']['peak_rss_mib']:.0f} MiB"]
    return "\n".join(lines)
