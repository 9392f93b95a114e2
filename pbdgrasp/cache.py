"""The strategy pipeline of Table I, cached: demonstration -> retargeting -> variation model per row.

Each step is cached under ``cache_dir`` by the SHA-256 of its inputs: the demonstration file, the scene,
object and hand files, the settings, the Python sources of the step (by their syntax trees without
docstrings, so an edit of a docstring, a comment or the layout recomputes nothing), the floating-point
kernels and a format version (:data:`CACHE_VERSION`). A re-run computes nothing twice; an edited input or
code is recomputed. The retargeting checks d6 in the demonstrated object's obstacle-free scene, as
``pbdgrasp retarget`` does; the variation model is solved with the row's scene, as ``pbdgrasp infer
--scene`` does.
"""

from __future__ import annotations

import ast
import hashlib
import json
import logging
import os
import platform
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import assets
from assets.errors import InputError

__all__ = [
    "CACHE_VERSION",
    "MODEL_SOURCES",
    "RETARGET_SOURCES",
    "SCENE_GRASP_SOURCES",
    "Strategy",
    "float_kernels",
    "prepare_strategy",
    "prepare_trajectory",
    "strategy_final_q",
]

log = logging.getLogger(__name__)

CACHE_VERSION = 1
"""Bump to invalidate every cached trajectory and model (a change of the pipeline's code)."""


def _sha256_file(path: str | os.PathLike) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _digest(parts: Iterable[str]) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(p.encode())
        h.update(b"\0")
    return h.hexdigest()


_PACKAGE_ROOT = Path(__file__).resolve().parent.parent
#: The code each cached step runs. Retargeting checks d6 in a pybullet world, so the world's code is part
#: of its key too.
#: The hand models, SE(3) helpers and q layout live in assets/ and are part of both keys.
_HAND_SOURCES = (
    "assets/se3.py",
    "assets/q_layout.py",
    "assets/kinematics.py",
    "assets/sah.py",
    "assets/human_hand.py",
)
MODEL_SOURCES = (
    "inference",
    "assets/sphere_cover.py",
    "assets/distance_fields.py",
    "planning/scene_fields.py",
    *_HAND_SOURCES,
    "planning/world.py",
    "planning/world_bodies.py",
    "planning/hand_urdf.py",
    "planning/scene.py",
    "planning/_pybullet.py",
    "pbdgrasp/scene_model.py",
)
#: The refined final grasp (retarget.final_grasp) solves a variation model and closes the hand, so the
#: retargeting's key holds the model's code and the closing's too.
RETARGET_SOURCES = (
    "retarget",
    "pbdgrasp/strategy.py",
    *MODEL_SOURCES,
    "planning/autograsp.py",
    "planning/grasp_quality.py",
)
#: The final grasp chosen again in the row's scene (pbdgrasp.scene_grasp): it closes the hand and solves
#: the model again, and measures the models as the planner draws them and follows their means (inspect), so
#: the model's key holds those sources too.
SCENE_GRASP_SOURCES = (
    "pbdgrasp/scene_grasp.py",
    "pbdgrasp/inspect.py",
    "planning/grasp_planner.py",
    "planning/collision.py",
    "planning/config_space.py",
    "pbdgrasp/strategy.py",
    "planning/closing_pool.py",
    "planning/autograsp.py",
    "planning/grasp_quality.py",
    "retarget/final_grasp.py",
)
#: Sources inside those folders that no cached step runs: the demonstration generator only writes the
#: demonstration files, whose contents are part of the retargeting key.
UNCACHED_SOURCES = (
    "assets/demonstrations/generate.py",
    "assets/demonstrations/hand_geometry.py",
    "assets/demonstrations/strategies.py",
)


def float_kernels() -> str:
    """The floating-point kernels this process computes with: the machine and the two variables that pin
    numpy's and OpenBLAS's kernels (the Makefile sets them on x86-64). Part of every cache key: the
    retargeting's result depends on them (chips' MSE 856 mm^2 with AVX2 kernels, 988 with AVX-512)."""
    pins = (f"{k}={os.environ.get(k, '')}" for k in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES"))
    return " ".join([platform.machine(), *pins])


def _source_digest(entries: Sequence[str]) -> str:
    """SHA-256 of the Python sources a cached step runs (folders or files relative to the package root),
    each by its code (:func:`_code_digest`): an edit of a docstring, a comment or the layout recomputes
    nothing."""
    files: list[Path] = []
    for e in entries:
        p = _PACKAGE_ROOT / e
        files += sorted(p.rglob("*.py")) if p.is_dir() else [p]
    files = [f for f in files if f.relative_to(_PACKAGE_ROOT).as_posix() not in UNCACHED_SOURCES]
    return _digest(f"{f.relative_to(_PACKAGE_ROOT)}:{_code_digest(f)}" for f in files if f.is_file())


def _code_digest(path: Path) -> str:
    """SHA-256 of a Python file's syntax tree without docstrings (comments and layout are not in the tree);
    of its bytes if it does not parse. The tree's dump may differ between Python versions, which then
    recompute the cache once."""
    try:
        tree = ast.parse(path.read_bytes())
    except (SyntaxError, ValueError):
        return _sha256_file(path)
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (
            isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
            and body
            and isinstance(body[0], ast.Expr)
            and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)
        ):
            node.body = body[1:] or [ast.Pass()]
    return hashlib.sha256(ast.dump(tree).encode()).hexdigest()


def _scene_files(scene) -> list[Path]:
    """Every file a scene's geometry comes from: the YAML, its object, object obstacles and meshes."""

    def object_files(name: str) -> list[Path]:
        return [assets.object_urdf(name), assets.object_mesh(name), assets.object_collision_mesh(name)]

    files = [Path(scene.path), *object_files(scene.object.name)]
    for ob in scene.obstacles:
        if ob.type == "object":
            files += object_files(ob.name)
        elif ob.type == "mesh":
            files += [Path(ob.file)] + ([Path(ob.collision_file)] if ob.collision_file else [])
    return files + [assets.hand_urdf(scene.hand)]


@dataclass(frozen=True)
class Strategy:
    """The learned strategy of one row: its cached files and the retargeting error.

    Attributes:
        row: the Table I row (scene).
        demonstration: the demonstration used (``Scene.strategy``).
        trajectory_path: the cached ``.traj.npz`` (tau_r, Sigma_r(t)).
        model_path: the cached ``.model.npz`` (the marginals, with the row's scene prior and constraints).
        model_sha256: the model file's hash (keys the workers' planner cache).
        mse_mm2: the retargeting fingertip MSE, mean over steps of the per-step mean square [mm^2].
    """

    row: str
    demonstration: str
    trajectory_path: Path
    model_path: Path
    model_sha256: str
    mse_mm2: float


def _missing(what: str, path: Path) -> InputError:
    return InputError(
        f"{what} is not cached (expected {path.name}); run without --report-only first", path.parent
    )


def prepare_trajectory(
    row: str,
    cache_dir: str | os.PathLike,
    progress: bool | None = False,
    retarget_max_nfev: int | None = None,
    *,
    build: bool = True,
    on_stage: Callable[[str], None] | None = None,
) -> Path:
    """The retargeted trajectory of a row's strategy (its demonstration retargeted in the demonstrated
    object's own scene), cached by the hash of its inputs.

    Args:
        row: a Table I row (scene name).
        cache_dir: the cache folder (created if missing).
        progress: the retargeting's tqdm bar.
        retarget_max_nfev: Rosenbrock evaluations per retargeting step (None: the retargeting's default).
        build: retarget on a cache miss (``False``: raise instead).
        on_stage: called with one line before a cache miss is computed.

    Returns:
        The cached ``.traj.npz`` path.

    Raises:
        InputError: a cache miss with ``build=False``.
    """
    from planning.scene import load_scene
    from retarget.demonstration import Demonstration
    from retarget.retargeting import RetargetConfig

    from .strategy import retarget_in_scene

    cache = Path(cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    scene = load_scene(row)
    demo_path = assets.demonstration_path(scene.strategy)
    demo = Demonstration.load(demo_path)
    demo_scene = load_scene(demo.object)
    config = RetargetConfig() if retarget_max_nfev is None else RetargetConfig(max_nfev=retarget_max_nfev)
    traj_key = _digest(
        [
            f"retarget v{CACHE_VERSION}",
            _source_digest(RETARGET_SOURCES),
            float_kernels(),
            _sha256_file(demo_path),
            repr(config),
        ]
        + [_sha256_file(assets.hand_urdf(h)) for h in ("sah", "human")]
        + [_sha256_file(f) for f in _scene_files(demo_scene)]
    )
    traj_path = cache / f"{scene.strategy}-{traj_key[:16]}.traj.npz"
    if not traj_path.is_file():
        if not build:
            raise _missing(f"the retargeted {scene.strategy} demonstration", traj_path)
        log.info("retargeting %s (cache miss) -> %s", scene.strategy, traj_path)
        if on_stage:
            on_stage(f"{row}: retargeting the {scene.strategy} demonstration ({demo.num_steps} steps)")
        traj, _ = retarget_in_scene(demo, demo_scene, config, progress=bool(progress))
        traj.save(traj_path)
    return traj_path


def prepare_strategy(
    row: str,
    cache_dir: str | os.PathLike,
    progress: bool | None = False,
    retarget_max_nfev: int | None = None,
    *,
    build: bool = True,
    on_stage: Callable[[str], None] | None = None,
) -> Strategy:
    """Demonstration -> retargeting -> inference for one row, each step cached by the hash of its inputs.

    Args:
        row: a Table I row (scene name).
        cache_dir: the cache folder (created if missing).
        progress: the retargeting's tqdm bar.
        retarget_max_nfev: Rosenbrock evaluations per retargeting step (None: the retargeting's default).
        build: compute a cache miss (``False``: raise instead).
        on_stage: called with one line before a cache miss is computed.

    Returns:
        The :class:`Strategy` with the cached file paths.

    Raises:
        InputError: a cache miss with ``build=False``.
    """
    from inference import VariationParams
    from planning.scene import load_scene
    from retarget.trajectory import Trajectory

    from .scene_grasp import SceneGraspConfig, adapt_final_grasp
    from .scene_model import learn_in_scene

    cache = Path(cache_dir)
    traj_path = prepare_trajectory(row, cache, progress, retarget_max_nfev, build=build, on_stage=on_stage)
    scene = load_scene(row)
    traj = Trajectory.load(traj_path)
    params = VariationParams()
    model_key = _digest(
        [f"infer v{CACHE_VERSION}", _source_digest(MODEL_SOURCES), float_kernels(), _sha256_file(traj_path)]
        + [json.dumps(params.to_dict(), sort_keys=True), _sha256_file(assets.hand_urdf("sah"))]
        + [_sha256_file(f) for f in _scene_files(scene)]
        + [_source_digest(SCENE_GRASP_SOURCES), repr(SceneGraspConfig())]
    )
    model_path = cache / f"{row}-{model_key[:16]}.model.npz"
    if not model_path.is_file():
        if not build:
            raise _missing(f"the variation model of {row}", model_path)
        log.info("inferring the variation model of %s (cache miss) -> %s", row, model_path)
        if on_stage:
            on_stage(f"{row}: solving the variation model in its scene (T = {traj.num_steps})")
        model = learn_in_scene(traj, scene, params, cache / "fields")
        if on_stage:
            on_stage(f"{row}: choosing the final grasp again in the scene")
        model = adapt_final_grasp(model, scene, params, cache / "fields")
        model.save(model_path)
    mse_mm2 = float(np.mean(np.asarray(traj.fingertip_rmse_mm) ** 2))
    return Strategy(row, scene.strategy, traj_path, model_path, _sha256_file(model_path), mse_mm2)


def strategy_final_q(strategy: Strategy) -> np.ndarray:
    """The strategy's mean final configuration (19,) in the row's world (for pictures)."""
    from inference.model import VariationModel
    from planning.scene import load_scene

    return VariationModel.load(strategy.model_path).world_means(load_scene(strategy.row).T_world_object)[-1]
