"""One filter step of the soil-stiffness estimator: any filter through its public methods, or a compiled step.

:class:`FilterSteps` is the part of
:class:`~terrain_estimation.estimators.soil_stiffness.SoilStiffnessEstimator`
that runs the filter over one step of the road: predict through the sub-steps,
then (unless the profile has a gap) the update with the measurement noise
``R_eff = R + G Σ_ε Gᵀ`` of the profile errors, gated on the NIS. The default
SCKF and EKF run as one compiled call (:mod:`.soil_stiffness_sckf`,
:mod:`.soil_stiffness_ekf`, the same results to rounding); any other filter, a
filter object passed in, or ``compiled=False`` runs the filter's public
``predict``/``update`` with the model's methods (:meth:`FilterSteps._filter_step`).
"""

# ruff: noqa: N806 - matrix symbols

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg.lapack import dpotrf as _dpotrf

from terrain_estimation.estimators.soil_stiffness_config import SoilStiffnessEstimatorConfig
from terrain_estimation.estimators.soil_stiffness_ekf import run_ekf_step
from terrain_estimation.estimators.soil_stiffness_kernels import STATUS_OK, ModelOperands
from terrain_estimation.estimators.soil_stiffness_sckf import run_step
from terrain_estimation.filters.base import Array, GaussianState, SqrtGaussianState
from terrain_estimation.models.quarter_car import LRVModel, QuarterCarModel

__all__ = ["FilterSteps"]


class FilterSteps:
    """Predict + update of one step, through the compiled step or the filter's public methods (module docstring)."""

    config: SoilStiffnessEstimatorConfig
    model: QuarterCarModel | LRVModel
    filter: Any
    _body_only: Any
    _c: dict[str, int]
    _operands: ModelOperands | None
    _r_base: dict[int, tuple[Array, Array]]
    _sckf: Any
    _ekf: Any

    def _measurement_noise_sqrt(self, x: Array, rows: int, sigma_eps: Array) -> Array:
        """``√R_eff``, ``R_eff = R + G Σ_ε Gᵀ`` with ``G`` the model's road-error gains.

        ``R`` of the first ``rows`` measurements is the model's constant
        ``√R √Rᵀ``, formed once per size. The factor is LAPACK ``dpotrf``
        called directly (the routine ``np.linalg.cholesky`` calls, at a
        fraction of its wrapper's cost); a matrix that is not positive
        definite raises ``numpy.linalg.LinAlgError`` as ``cholesky`` does.
        """
        base = self._r_base.get(rows)
        if base is None:
            rs = self.model.measurement_noise_sqrt()[:rows, :rows]
            # [g_h, g_ḣ] with the constant g_ḣ = D filled in (g_h is C(x̄) B, per step).
            gain0 = np.zeros((rows, 2))
            gain0[:, 1] = self.model.profile_error_gains(x)[1][:rows]
            base = self._r_base[rows] = (rs @ rs.T, gain0)
        r, gain0 = base
        gain = gain0.copy()
        gain[:, 0] = self.model._road_gain(x)[:rows]
        r_eff = r + gain @ sigma_eps @ gain.T
        factor, info = _dpotrf(0.5 * (r_eff + r_eff.T), lower=1, clean=1)
        if info != 0:
            raise np.linalg.LinAlgError("Matrix is not positive definite")
        return np.asarray(factor)

    def _measurement(self, zb: float, zw: float | None) -> tuple[Any, Array]:
        """The model and measurement vector of an update: both accelerometers, or the body's alone."""
        if self._body_only is None:
            return self.model, np.array([zb])
        if zw is None:
            return self._body_only, np.array([zb])
        return self.model, np.array([zb, zw])

    def _filter_step(
        self, prev_state: Any, u: Any, dt: float, max_gap: float, zb: float, zw: float | None, sigma_eps: Array
    ) -> tuple[Any, Any, float, bool, int]:
        """Predict and (unless the profile has a gap) update with any filter: ``(prior, post, nis, accepted, dim)``.

        ``dim`` is the measurement size of the update (0 for predict-only).
        Raises what the filter raises (ValueError, LinAlgError).
        """
        cfg = self.config
        nis, accepted = 0.0, False
        update_dim = 0
        prior = self.filter.predict(prev_state, self.model, u, dt)
        post = prior
        if max_gap > cfg.profile_max_gap_s:
            self._c["predict_only"] += 1
            return prior, post, nis, accepted, update_dim
        model, z = self._measurement(zb, zw)
        if cfg.profile_noise_std > 0.0:
            rs = self._measurement_noise_sqrt(np.asarray(prior.x), z.size, sigma_eps)
            post, info = self.filter.update(prior, z, model, u, measurement_noise_sqrt=rs)
        else:
            post, info = self.filter.update(prior, z, model, u)
        nis = float(info.nis)
        accepted = bool(info.accepted)
        update_dim = z.size
        if accepted and cfg.gate_threshold is not None and not (nis <= cfg.gate_threshold):
            accepted = False
        if not accepted:
            self._c["gated"] += 1
            post = prior
        else:
            self._c["updates_accepted"] += 1
        return prior, post, nis, accepted, update_dim

    def _compiled_step(
        self,
        prev_state: Any,
        u: Any,
        dt: float,
        max_gap: float,
        zb: float,
        zw: float | None,
        sigma_eps: Array,
    ) -> tuple[Any, Any, float, bool, int]:
        """:meth:`_filter_step` for the default SCKF or EKF, in one compiled call.

        :func:`.soil_stiffness_sckf.sckf_step` or :func:`.soil_stiffness_ekf.ekf_step`: the same filter and
        model as the filter's public ``predict``/``update`` with the model's methods, to rounding (about 1e-13
        relative per step): the numpy form of a 5-state step is mostly per-call overhead. A failed step
        (non-finite points, model output or Jacobian, ``R_eff`` not positive definite) raises ValueError, as
        the public methods raise there.
        """
        cfg = self.config
        ops = self._operands
        sckf = self.filter is self._sckf
        assert ops is not None and (sckf or self.filter is self._ekf)
        update = max_gap <= cfg.profile_max_gap_s
        z = self._measurement(zb, zw)[1] if update else None
        run = run_step if sckf else run_ekf_step
        factor = prev_state.S if sckf else prev_state.P
        args = (z, sigma_eps, cfg.profile_noise_std > 0.0, self.filter.gate_threshold)
        status, x_pred, f_pred, nis, accepted, x_post, f_post = run(ops, self.model, prev_state.x, factor, u, dt, *args)
        if status != STATUS_OK:
            raise ValueError(
                f"{'SCKF' if sckf else 'EKF'} step failed: non-finite points or model output, or a measurement "
                "noise that is not positive definite"
            )
        prior: Any
        post: Any
        if sckf:
            prior, post = SqrtGaussianState(x=x_pred, S=f_pred), SqrtGaussianState(x=x_post, S=f_post)
        else:
            prior, post = GaussianState(x=x_pred, P=f_pred), GaussianState(x=x_post, P=f_post)
        if z is None:
            self._c["predict_only"] += 1
            return prior, prior, 0.0, False, 0
        gate = cfg.gate_threshold
        if accepted and gate is not None and not (nis <= gate):
            accepted = False
        if not accepted:
            self._c["gated"] += 1
            return prior, prior, nis, False, z.size
        self._c["updates_accepted"] += 1
        return prior, post, nis, True, z.size
