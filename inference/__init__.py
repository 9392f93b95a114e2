"""The variation model: a GTSAM factor graph over the object pose and the hand trajectory (paper V-VII)."""

from .model import VariationModel, build_graph, factor_covariances, initial_values, solve
from .params import VariationParams
from .sampler import MixtureSample, MixtureSampler, sample, sample_marginal, sample_object

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
