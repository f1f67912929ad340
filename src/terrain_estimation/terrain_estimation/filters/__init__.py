"""Generic Gaussian filters over a shared model protocol (numpy/scipy only).

Every filter is a frozen configuration object with the same steps over an
immutable state value (see :mod:`.base`)::

    state = filt.initial_state(x0, P0)
    state = filt.predict(state, model, u, dt)
    state, info = filt.update(state, z, model, u)

| filter | state | module |
|---|---|---|
| :class:`KalmanFilter` (linear reference, takes matrices) | ``GaussianState`` | ``kalman`` |
| :class:`ExtendedKalmanFilter` | ``GaussianState`` | ``ekf`` |
| :class:`UnscentedKalmanFilter` | ``GaussianState`` | ``ukf`` |
| :class:`CubatureKalmanFilter` | ``GaussianState`` | ``ckf`` |
| :class:`SquareRootCubatureKalmanFilter` | ``SqrtGaussianState`` | ``sckf`` |

Strong tracking and noise adaptation for the (AN-)STUKF are pure functions in
:mod:`.adaptive`. Divergence detection and recovery from the last good
estimate (on top of each filter's innovation gate) are in :mod:`.faults`.
"""

from .adaptive import (
    NoiseAdaptation,
    StrongTrackingConfig,
    StrongTrackingPrediction,
    adapt_noise_sqrt,
    innovation_is_consistent,
    strong_tracking_predict,
    suboptimal_fading_factor,
)
from .base import (
    Array,
    GaussianState,
    JacobianModel,
    SqrtGaussianState,
    StateSpaceModel,
    UpdateInfo,
    check_square,
    check_vector,
    nis_gate,
)
from .ckf import CubatureKalmanFilter
from .ekf import ExtendedKalmanFilter
from .faults import (
    DivergenceCheck,
    DivergenceConfig,
    DivergenceMonitor,
    guarded_step,
    nis_band,
    sqrt_factor_fault,
)
from .kalman import KalmanFilter
from .sckf import SquareRootCubatureKalmanFilter
from .sigma_points import (
    CubaturePoints,
    MerweScaledSigmaPoints,
    SigmaPointSet,
    cubature_points,
    merwe_scaled_sigma_points,
    robust_sqrt,
    tria,
)
from .ukf import (
    MeasurementMoments,
    SigmaPointKalmanFilter,
    SigmaPointPrediction,
    UnscentedKalmanFilter,
)

__all__ = [
    # base vocabulary
    "Array",
    "GaussianState",
    "SqrtGaussianState",
    "UpdateInfo",
    "StateSpaceModel",
    "JacobianModel",
    "check_vector",
    "check_square",
    "nis_gate",
    # sigma points
    "SigmaPointSet",
    "CubaturePoints",
    "MerweScaledSigmaPoints",
    "cubature_points",
    "merwe_scaled_sigma_points",
    "tria",
    "robust_sqrt",
    # filters
    "KalmanFilter",
    "ExtendedKalmanFilter",
    "SigmaPointKalmanFilter",
    "SigmaPointPrediction",
    "MeasurementMoments",
    "UnscentedKalmanFilter",
    "CubatureKalmanFilter",
    "SquareRootCubatureKalmanFilter",
    # adaptive building blocks
    "StrongTrackingConfig",
    "StrongTrackingPrediction",
    "NoiseAdaptation",
    "innovation_is_consistent",
    "suboptimal_fading_factor",
    "strong_tracking_predict",
    "adapt_noise_sqrt",
    # faults
    "DivergenceConfig",
    "DivergenceCheck",
    "DivergenceMonitor",
    "guarded_step",
    "nis_band",
    "sqrt_factor_fault",
]
