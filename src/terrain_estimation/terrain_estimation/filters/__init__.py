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

from . import base, faults, sigma_points
from .adaptive import (
    NoiseAdaptation,
    StrongTrackingConfig,
    StrongTrackingPrediction,
    adapt_noise_sqrt,
    innovation_is_consistent,
    strong_tracking_predict,
    suboptimal_fading_factor,
)
from .base import *  # noqa: F403 - the whole public list (see __all__)
from .ckf import CubatureKalmanFilter
from .ekf import ExtendedKalmanFilter
from .faults import *  # noqa: F403 - the whole public list (see __all__)
from .kalman import GatedFilter, KalmanFilter
from .sckf import SquareRootCubatureKalmanFilter
from .sigma_points import *  # noqa: F403 - the whole public list (see __all__)
from .ukf import (
    MeasurementMoments,
    SigmaPointKalmanFilter,
    SigmaPointPrediction,
    UnscentedKalmanFilter,
)

__all__ = [
    # filters
    "GatedFilter",
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
]
# The base vocabulary, the sigma points and the fault handling: each module's whole public list.
__all__ += base.__all__
__all__ += sigma_points.__all__
__all__ += faults.__all__
