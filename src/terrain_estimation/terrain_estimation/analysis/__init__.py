"""Offline analysis of the estimators: performance bounds (numpy/scipy only).

* :func:`pcrlb` — posterior Cramér–Rao lower bound (Tichavský et al. 1998) of
  any :class:`~terrain_estimation.filters.base.JacobianModel` along given truth
  trajectories (module ``pcrlb``).
* :func:`pcrlb_quarter_car` — the same for the quarter car, truth simulated
  by ``vehicle_sim``, reported as a bound on the soil stiffness k_s.
"""

from terrain_estimation.analysis.pcrlb import (
    DEFAULT_P0_DIAG,
    PcrlbResult,
    QuarterCarPcrlb,
    pcrlb,
    pcrlb_quarter_car,
    quarter_car_truth,
)

__all__ = [
    "DEFAULT_P0_DIAG",
    "PcrlbResult",
    "QuarterCarPcrlb",
    "pcrlb",
    "pcrlb_quarter_car",
    "quarter_car_truth",
]
