"""ROS-free estimator cores that nodes and offline runners drive (numpy/scipy only).

The soil-stiffness names below are loaded on first use (PEP 562): importing one estimator (the skid
steer's, say) does not import the others and their compiled steps (issue 23: start-up).
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = [
    "EstimatorCounters",
    "SoilStiffnessEstimate",
    "SoilStiffnessEstimator",
    "SoilStiffnessEstimatorConfig",
    "make_filter",
]


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(importlib.import_module("terrain_estimation.estimators.soil_stiffness"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
