"""``pbdgrasp bench``: the performance figures of every stage, measured in one process (issue 9).

Prints a table (the machine first) or, with ``--json``, the full results as JSON on stdout; ``-o`` also
writes the JSON to a file (atomically). See :mod:`pbdgrasp.bench` for what is measured and how.
"""

from __future__ import annotations

import json
import sys

NAME = "bench"
HELP = "measure inference, sampling, collision, quality, retargeting and planning speed on this machine"
ORDER = 90


def add_arguments(p) -> None:
    p.add_argument("--quick", action="store_true", help="tiny settings (seconds): ham planning only")
    p.add_argument("--trials", type=int, default=3, help="planning trials per scene and planner (default 3)")
    p.add_argument("--time-limit-s", type=float, default=10.0, help="budget of one planning query [s]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print the results as JSON instead of the table")
    p.add_argument("-o", "--output", metavar="BENCH.json", help="also write the JSON results here")
    p.add_argument("--cache-dir", default="results/cache/bench", help="cached planning strategies")
    p.add_argument(
        "--retarget-max-nfev", type=int, default=100, help="Rosenbrock evaluations per step (strategies)"
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
    from pbdgrasp.bench import BenchConfig, format_table, run_bench

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
