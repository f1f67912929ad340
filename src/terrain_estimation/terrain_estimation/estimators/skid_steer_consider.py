"""Consider covariance of the skid-steer estimate: what uncertain tire and terrain parameters do to it.

The observer sees ``v_x`` and ``v_y`` only through its tire model: the
measured specific force fixes the tire forces, and the model turns them into
slip velocities. A parameter the filter does not estimate (the longitudinal
stiffness, the friction below saturation, the motion resistance of the
ground) biases the velocities by the slip it would change, and no process
noise describes that: the bias is not white and the innovations do not show
it (the filter's prediction agrees with the measurement through the wrong
model). On the independent truth plant the unscaled covariance claims a
``v_x`` 3–10× more certain than it is (docs/results/skid_steer_fair.md).

Estimating such parameters does not help where they are not observable:
as states (or Schmidt "consider" states inside the sigma-point set) they
wander with the model error and bias the motion states further (in
development runs on the truth plant, not kept on the results page: RMS
``v_x`` error 5–20× the nominal filter's). Here they are *considered*
in the classical sense (Schmidt 1966; Tapley, Schutz & Born, *Statistical
Orbit Determination*, 6.3; Simon, *Optimal State Estimation*, 7.6): the
filter's estimate is left as it is, and the sensitivity of its error to each
parameter's deviation is carried alongside,

    Ψ⁻_k = F_s Ψ⁺_{k−1} − F_c,          Ψ⁺_k = (I − K H_s) Ψ⁻_k + K H_c,

with ``F = ∂f/∂[s, c]`` and ``H_c = ∂h/∂c`` at the filter's mean (forward
differences of the observer's own ``f`` and ``h`` with the parameters as
extra states at their nominal values), the filter's gain
``K = P_xz P_zz⁻¹`` and its own statistical linearisation of the update,
``I − K H_s = P⁺ P̄⁻¹`` (the sigma points' slope, not a forward difference:
near the brush model's rolling-speed floor the local slope is far steeper
than what the points see, and a gain paired with it makes the recursion
unstable). The published covariance is
``P + Ψ C Ψᵀ`` with ``C = diag(σ_c²)`` the parameters' mean-square
deviation from the nominal: the mean-square error of a filter that uses the
nominal value when the truth is off by ``σ_c``, to first order.

A zero-velocity update (the vehicle stands still) resets ``Ψ``: at rest the
estimate no longer depends on the tire law.

The signs follow from ``e = x̂ − x`` and ``δ = c − ĉ`` (truth minus the
filter's nominal): ``e⁻ ≈ F_s e − F_c δ`` and ``e⁺ ≈ (I − K H_s) e⁻ + K (H_c δ + v)``.
Before issue 20's second round the measurement term had the opposite sign;
the variances were then sized around it (C_x 5 %) and were too cautious in
``v_y`` on the bank and in the sharp turn (e²/σ² 0.59, 0.32) and
over-confident in the S-curve (4.9), as no single size fits a recursion whose
update term pushes the wrong way. With the sign as derived, one size fits
them: C_x 15 % gives ``v_y`` e²/σ² 1.2, 1.0, 1.6, 1.2 on the nominal turn,
the bank, the sharp turn and the S-curve, and NEES windows in band 91, 81,
94, 97 % (seeds 1000–1002, where it was chosen; 89, 91, 94, 100 % on seeds
1003–1005). The S-curve's ``v_y`` error is a 12 % gain error in phase with
``v_y`` (a 40 ms lag, the tire relaxation the observer lacks, is 4–5 % of its
mean square), which is what the C_x sensitivity describes there.

**Friction** (``consider.friction``, its own size ``friction_std``; off by
default). The brush force at a fixed slip is ``μ F_z g(t)`` with ``t`` the
sliding fraction of the patch, so ``∂ln F/∂ln μ = t (3 − 2t)/(3 − 3t + t²)``:
0 at low utilisation, 1 when the tire slides. On a straight run it is ~0 (the
observer's tires at ``t`` ≈ 0.01 on the straight acceleration run: a friction
term leaves every figure as it is). But a skid-steer vehicle turns by sliding
its tires: in every turn of the reproduction the observer's tires of one side
are at ``t`` = 1 and the others at 0.5–0.9 (``∂ln F/∂ln μ`` 0.85–0.9 on the
nominal turn, the bank, the μ patch, the sharp turn, C_α +30 %). The first
order holds: rerun with μ × 0.9 and × 1.1, the filter's ``v_y`` moves by
0.045 and 0.035 m/s (RMS) in the sharp turn against 0.040 from ``Ψ`` with
``friction_std`` 0.1, 0.0008/0.0006 against 0.0006 on the nominal turn,
0.0047/0.0038 against 0.0042 on the bank (seed 1000). In the sharp turn
(3 m/s, 0.6 rad/s) a 10 % friction error moves ``v_y`` by 5× the filter's
σ; the truth plant's μ there is the nominal one, so any friction term makes
it far too cautious (NEES windows in band 94 % → 0-3 % at 10, 20, 30 %;
``v_y`` e²/σ² 1.56 → 0.05, 0.01, 0.01; the bank 94 % → 69, 53, 53 %; 2
seeds), while on the μ patch (μ halved) ``v_y`` e²/σ² only falls from 176
to 163, 139, 117. There the error is a friction the data do not show: the
observer given the patch's μ has a mean ``v_y`` error of 0.0014 m/s on it
against 0.016 with the nominal μ, yet with the nominal μ its whitened
innovations on the steady patch have mean ≈ 0 and mean square ≈ 1 per
channel and its Q scale sits at its floor; the effect grows faster than
linearly as μ falls (0.0007 m/s per 10 % at the nominal μ, 0.015 m/s at
μ × 0.5). A friction scale state does not learn it either (it takes up the
brush law's shape error: nominal |e_β| 1.6 → 8.9 mrad, 21 with a 30 s
reversion), and inflating the published covariance by the windowed NIS
excess reaches 39-44 % of the patch's windows (from 33-39 %). So the
default does not consider the friction; a user who knows the ground less
well than the reproduction's scenarios do switches it on.

**Known limitation.** The motion resistance, nominal 0 and clipped at 0 in
the model, gets ``F_c = 0`` from the downward step along ``[Ψ; −I]``, so for
it only the measurement term acts. With that process term restored (and the
earlier sign) the straight-acceleration run was 26× over-confident in
``v_x`` (20 seeds); it is left as the recursion that is held to the errors on
the truth runs (docs/results/skid_steer_fair.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from terrain_estimation.checks import check_non_negative
from terrain_estimation.filters.base import Array
from terrain_estimation.models.skid_steer_scales import (
    GRAVITY_NAMES,
    RESISTANCE_NAME,
    STATE_NAMES,
    TireScaleConfig,
    _ScaledModelBase,
    state_names,
)

__all__ = ["CONSIDER_NAMES", "ConsiderConfig", "ConsiderCovariance"]

#: Parameters that can be considered: the tire scales and the motion-resistance coefficient (not the ground
#: slope, a state of the filter or nothing).
CONSIDER_NAMES: tuple[str, ...] = tuple(name for name in STATE_NAMES if name not in GRAVITY_NAMES)


@dataclass(frozen=True)
class ConsiderConfig:
    """Which parameters are considered, and how uncertain they are.

    Attributes:
        parameters: names from :data:`CONSIDER_NAMES`; a parameter the model
            estimates (``tire_scales.states``) is skipped. Empty: off.
            Default: the motion resistance, which the brush observer leaves
            out and which sets the longitudinal slip of every steady run, and
            the longitudinal stiffness, which stands for the brush law's error
            in shape along the slip (a real tire's force is not the brush
            law's at any C_x).
        scale_std: root-mean-square deviation of ``ln s`` of each considered
            tire scale. Default 0.15: the longitudinal slip stiffness of a
            tire nobody measured, and the brush law's error in shape along
            the slip, known to about ±15 %. Chosen on the nominal truth run
            as the setting of ``skid_compare --consider`` whose ``v_y``
            e²/σ² is nearest 1 (1.2; 0.75 at 20 %, 2.0 at 10 %), and it
            holds on the bank, the sharp turn and the S-curve (module
            docstring).
        friction_std: root-mean-square deviation of ``ln s_μ`` when the
            friction is considered (its own size: a friction coefficient
            varies between surfaces far more than a tire's stiffness does).
            Default 0.3: μ of one tire on firm ground within about ±30 %
            (peak μ: dry asphalt 0.8–0.9, wet 0.5–0.7, gravel 0.6; Wong,
            *Theory of Ground Vehicles*, ch. 1). Not considered by default (module
            docstring, "Friction").
        resistance_rms: root-mean-square motion-resistance coefficient the
            observer's model leaves out (force per unit normal load). Default
            0.02: pneumatic tires on firm ground (0.01–0.03, Wong, *Theory of
            Ground Vehicles*, ch. 1); 0.05–0.1 on grass or soft soil. It is
            also the simulator's nominal value.
        step: forward-difference steps of the Jacobians, relative to
            ``(1 m/s, 1 m/s, 1 rad/s, 1, …)``.
    """

    parameters: tuple[str, ...] = ("longitudinal_stiffness", RESISTANCE_NAME)
    scale_std: float = 0.15
    friction_std: float = 0.3
    resistance_rms: float = 0.02
    step: float = 1e-5

    def __post_init__(self) -> None:
        # CONSIDER_NAMES is STATE_NAMES without the slope: the names and their order.
        object.__setattr__(self, "parameters", state_names("consider.parameters", self.parameters))
        if set(self.parameters) & set(GRAVITY_NAMES):
            raise ValueError(f"consider.parameters cannot hold the ground slope {GRAVITY_NAMES}, got {self.parameters}")
        for name in ("scale_std", "friction_std", "resistance_rms"):
            check_non_negative("consider", name, getattr(self, name))
        if not (math.isfinite(self.step) and 0.0 < self.step <= 1e-2):
            raise ValueError(f"consider.step must be in (0, 0.01], got {self.step}")

    def variance(self, name: str) -> float:
        """The mean-square deviation of the considered parameter ``name`` (``ln s`` of a scale, the
        motion-resistance coefficient itself)."""
        if name == RESISTANCE_NAME:
            return self.resistance_rms**2
        return (self.friction_std if name == "friction" else self.scale_std) ** 2


class ConsiderCovariance:
    """The sensitivity ``Ψ`` of the estimate to the considered parameters (module docstring).

    Args:
        config: the considered parameters.
        model: the filter's observer model (a ``*_scales`` or plain model of
            :mod:`terrain_estimation.models`).
        augmented: the same model with the considered parameters as extra
            states (built by :meth:`for_estimator`).
        filter_states: the filter's added states (``model``'s extra names).
    """

    def __init__(self, config: ConsiderConfig, model: Any, augmented: Any, filter_states: tuple[str, ...]) -> None:
        self.config = config
        self.model = model
        self.augmented = augmented
        extra = augmented.scales.states
        self.considered = tuple(p for p in config.parameters if p not in filter_states)
        n_s = 3 + len(filter_states)
        self._s = np.array([0, 1, 2, *(3 + extra.index(p) for p in filter_states)], dtype=int)
        self._c = np.array([3 + extra.index(p) for p in self.considered], dtype=int)
        self._n_aug = 3 + len(extra)
        self._x_nominal = np.zeros(self._n_aug)
        self._C = np.diag([config.variance(p) for p in self.considered])
        self.psi = np.zeros((n_s, len(self.considered)))
        self._cov: Array | None = None  # Ψ C Ψᵀ of the current Ψ when known (set_sensitivity)

    @classmethod
    def for_estimator(cls, config: ConsiderConfig, estimator_config: Any, model: Any) -> ConsiderCovariance | None:
        """The consider covariance of an estimator's model, or None when nothing is considered."""
        filter_states = tuple(estimator_config.scale_states)
        considered = tuple(p for p in config.parameters if p not in filter_states)
        if not considered:
            return None
        base = (
            estimator_config.tire_scales if estimator_config.model.endswith("_scales") else TireScaleConfig(states=())
        )
        # The considered parameters as extra states at the filter's nominal model: scales 1 and no resistance.
        scales = replace(base, states=filter_states + considered, resistance_nominal=0.0)
        kind = (
            estimator_config.model if estimator_config.model.endswith("_scales") else estimator_config.model + "_scales"
        )
        # The same measurement as the filter's (a kinematic model chooses its yaw-moment row by its states).
        augmented = replace(estimator_config, model=kind, tire_scales=scales).make_model(
            yaw_moment=getattr(model, "yaw_moment", None)
        )
        # The filter's nominal model serves the augmented one: the per-step terms (loads, rolling speeds) of an
        # input are then computed once per step, by whichever evaluates them first.
        augmented.base = model.base if isinstance(model, _ScaledModelBase) else model
        return cls(config, model, augmented, filter_states)

    @property
    def count(self) -> int:
        """Number of considered parameters."""
        return len(self.considered)

    def reset(self) -> None:
        """Forget the sensitivity: a (re)start, or a zero-velocity update."""
        self.psi = np.zeros(self.psi.shape)
        self._cov = None

    def set_sensitivity(self, psi: Array, covariance: Array) -> None:
        """Take ``Ψ`` and its ``Ψ C Ψᵀ`` as computed elsewhere for this step (the compiled step of
        :mod:`~terrain_estimation.estimators.skid_steer_compiled`, the same arithmetic as :meth:`step` and
        :meth:`covariance`)."""
        self.psi = psi
        self._cov = covariance

    def _directional(self, fn: Any, x: Array, directions: Array) -> Array:
        """Forward-difference derivatives ``(rows, k)`` of ``fn`` (``f`` or ``h`` over points) at the filter
        mean ``x`` along the augmented-state ``directions`` ``(n_aug, k)``: one evaluation per direction."""
        xa = self._x_nominal.copy()
        xa[self._s] = x
        scale = np.maximum(np.abs(directions).max(axis=0), 1.0)
        eps = self.config.step / scale
        points = np.repeat(xa[None, :], directions.shape[1] + 1, axis=0)
        points[1:] += (directions * eps).T
        out = np.asarray(fn(points), dtype=float)
        return ((out[1:] - out[0]) / eps[:, None]).T

    def step(self, x_prev: Array, x_post: Array, result: Any, P_post: Array, u: Any, dt: float) -> None:
        """Carry ``Ψ`` over one filter step.

        ``F_s Ψ − F_c`` is the derivative of ``f`` along ``[Ψ; −I]`` (one
        direction per considered parameter, not a full Jacobian), and ``H_c``
        that of ``h`` along the parameters.

        Args:
            x_prev: the previous posterior mean (the prediction's linearisation point).
            x_post: the posterior mean (where ``H_c`` is taken).
            result: the filter's :class:`~terrain_estimation.filters.an_stukf.AnStukfResult`
                (``prior_cov``, ``cross_cov``, ``innovation_cov``, ``accepted``).
            P_post: the posterior covariance.
            u, dt: the step's input and length.

        Raises:
            ValueError: a derivative is not finite or the filter's moments are missing (the caller resets).
        """
        k = self.count
        directions = np.zeros((self._n_aug, k))
        directions[self._s] = self.psi
        directions[self._c, np.arange(k)] = -1.0
        psi = self._directional(lambda pts: self.augmented.f(pts, u, dt), np.asarray(x_prev, dtype=float), directions)
        psi = psi[self._s]
        if result.accepted:
            if result.prior_cov is None or result.cross_cov is None:
                raise ValueError("consider covariance: the filter did not report its update's moments")
            # The filter's own linearisation: P⁺ P̄⁻¹ = I − K H̃_s (its points, not a forward difference,
            # which is far steeper than the sigma points see near the brush model's rolling-speed floor).
            unit = np.zeros((self._n_aug, k))
            unit[self._c, np.arange(k)] = 1.0
            H_c = self._directional(lambda pts: self.augmented.h(pts, u), np.asarray(x_post, dtype=float), unit)
            K = np.linalg.solve(np.asarray(result.innovation_cov, dtype=float), np.asarray(result.cross_cov).T).T
            psi = np.asarray(P_post, dtype=float) @ np.linalg.solve(result.prior_cov, psi) + K @ H_c
        if not np.isfinite(psi).all():
            raise ValueError("consider covariance: the sensitivity is not finite")
        self.psi = psi
        self._cov = None

    def covariance(self) -> Array:
        """``Ψ C Ψᵀ`` ``(n_s, n_s)``: what the considered parameters add to the filter's covariance."""
        if self._cov is not None:
            return self._cov
        a = self.psi * np.sqrt(np.diag(self._C))
        m = a @ a.T
        return 0.5 * (m + m.T)  # exactly symmetric (the published covariances are checked for it)
