"""The soil-stiffness estimator a configuration selects: profile-fed or profile-free.

A module of its own so that neither estimator imports the other's module back
(the profile-free estimator builds on the profile-fed one's configuration).
"""

from __future__ import annotations

from typing import Any

from terrain_estimation.estimators.soil_profile_free import ProfileFreeSoilStiffnessEstimator
from terrain_estimation.estimators.soil_stiffness import SoilStiffnessEstimator, SoilStiffnessEstimatorConfig

__all__ = ["make_estimator"]


def make_estimator(config: SoilStiffnessEstimatorConfig | None = None) -> Any:
    """The estimator ``config.road_input`` selects: :class:`SoilStiffnessEstimator` (profile) or the profile-free one.

    Raises:
        ValueError: a configuration the selected mode cannot run.
    """
    cfg = config if config is not None else SoilStiffnessEstimatorConfig()
    if cfg.road_input == "stochastic":
        return ProfileFreeSoilStiffnessEstimator(cfg)
    return SoilStiffnessEstimator(cfg)
