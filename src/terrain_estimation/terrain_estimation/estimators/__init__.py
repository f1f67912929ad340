"""ROS-free estimator cores that nodes and offline runners drive (numpy/scipy only)."""

from terrain_estimation.estimators.soil_stiffness import (
    EstimatorCounters,
    SoilStiffnessEstimate,
    SoilStiffnessEstimator,
    SoilStiffnessEstimatorConfig,
    make_filter,
)

__all__ = [
    "EstimatorCounters",
    "SoilStiffnessEstimate",
    "SoilStiffnessEstimator",
    "SoilStiffnessEstimatorConfig",
    "make_filter",
]
