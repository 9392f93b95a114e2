"""The variation model (paper sections V-VI): a GTSAM factor graph over the object pose and the hand
trajectory, solved in a scene, its marginals P(X_t | O) and the mixture P(Y) sampled from them.

Modules: :mod:`~inference.params` (parameters, YAML), :mod:`~inference.factors` (the factors),
:mod:`~inference.graph` (the graph), :mod:`~inference.clearance` (the clearance margins of a sphere-covered
hand), :mod:`~inference.joint_limits` (joint limits by expectation propagation),
:mod:`~inference.clearance_sites` (the clearance in the marginals, opt-in), :mod:`~inference.contact` (the
demonstrated contacts held at the grasp), :mod:`~inference.sweep` (a start from the grasp backwards),
:mod:`~inference.solve` (the solve and the marginals), :mod:`~inference.model` (the result and its
``.model.npz`` file), :mod:`~inference.sampler` (P(Y)).
"""

from .graph import build_graph, factor_covariances, initial_values
from .model import VariationModel
from .params import VariationParams
from .sampler import MixtureSample, MixtureSampler, sample, sample_marginal, sample_object
from .solve import solve

__all__ = [
    "MixtureSample",
    "MixtureSampler",
    "VariationModel",
    "VariationParams",
    "build_graph",
    "factor_covariances",
    "initial_values",
    "sample",
    "sample_marginal",
    "sample_object",
    "solve",
]
