"""The compiled EKF step (``estimators.soil_stiffness_ekf``) is the EKF of the public methods.

The reference is :class:`~terrain_estimation.filters.ekf.ExtendedKalmanFilter`'s
``predict``/``update`` with the model's own ``f``, ``h``, Jacobians and noise
factors; the estimator runs it with ``compiled=False`` (or after
``set_compiled_steps(False)``). The compiled step writes the small products,
the Cholesky factor and the triangular solves out, so the comparison is to
rounding, not bit for bit: 1e-12 relative over whole rides, where the
reference filter itself is stable (a filter thrown between the clamps of its
stiffness state amplifies any rounding difference, whichever path runs).
"""

# ruff: noqa: N806 - matrix symbols

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from terrain_estimation.estimators.soil_stiffness import (
    SoilStiffnessEstimate,
    SoilStiffnessEstimator,
    SoilStiffnessEstimatorConfig,
    _BodyOnly,
    set_compiled_steps,
)
from terrain_estimation.estimators.soil_stiffness_ekf import ekf_step, run_ekf_step
from terrain_estimation.estimators.soil_stiffness_kernels import STATUS_FAILED, STATUS_OK, model_operands
from terrain_estimation.filters.base import GaussianState
from terrain_estimation.filters.ekf import ExtendedKalmanFilter
from terrain_estimation.models.quarter_car import (
    LRVModel,
    LRVParams,
    QuarterCarModel,
    QuarterCarParams,
    StepInput,
)

BAGS = Path(__file__).resolve().parents[1] / "bags"
RNG_SEED = 20261127
STEP_RTOL = 1e-9  # one step from random states (some far from anything a ride reaches)
RIDE_RTOL = 1e-12  # whole rides, per state / variance against its largest magnitude over the ride


def _models() -> list[Any]:
    return [
        QuarterCarModel(QuarterCarParams(stiffness_state="k_tot")),
        QuarterCarModel(QuarterCarParams(stiffness_state="log_k_s")),
        QuarterCarModel(QuarterCarParams(ktot_noise_form="printed")),
        QuarterCarModel(QuarterCarParams(ekf_jacobian="paper")),
        QuarterCarModel(QuarterCarParams(ekf_jacobian="paper", stiffness_state="log_k_s")),
        LRVModel(LRVParams(relative_damper=True, stiffness_state="log_k_s")),
        LRVModel(LRVParams(relative_damper=False, stiffness_state="k_tot")),
        LRVModel(LRVParams(relative_damper=True, ekf_jacobian="paper", ktot_noise_form="printed")),
    ]


def _reference(model: Any, state: GaussianState, u: Any, dt: float, z: np.ndarray, sigma_eps: Any, gate: Any) -> Any:
    """Predict and update through the public EKF and the model's methods: ``(prior, nis, accepted, post)``."""
    filt = ExtendedKalmanFilter(gate_threshold=gate)
    prior = filt.predict(state, model, u, dt)
    p = z.size
    meas = model if p == model.measurement_dim else _BodyOnly(model)
    rs = None
    if sigma_eps is not None:
        g_h, g_d = model.profile_error_gains(prior.x)
        gain = np.stack([g_h[:p], g_d[:p]], axis=1)
        r_eff = np.diag(model.measurement_noise_sqrt().diagonal()[:p] ** 2) + gain @ sigma_eps @ gain.T
        rs = np.linalg.cholesky(r_eff)
    post, info = filt.update(prior, z, meas, u, measurement_noise_sqrt=rs)
    return prior, float(info.nis), bool(info.accepted), post


def _close(got: Any, want: Any, rtol: float) -> bool:
    got, want = np.asarray(got), np.asarray(want)
    scale = max(float(np.max(np.abs(want))), 1e-300)
    return bool(np.all(np.abs(got - want) <= rtol * scale))


def _cov_close(got: Any, want: Any, rtol: float) -> bool:
    d = np.sqrt(np.abs(np.diag(want)))
    return bool(np.all(np.abs(got - want) <= rtol * np.maximum(np.outer(d, d), 1e-300)))


@pytest.mark.parametrize("index", range(8))
@pytest.mark.parametrize("gate", [None, 3.0])
def test_compiled_step_equals_the_public_filter(index: int, gate: float | None) -> None:
    """Prior, NIS, gate decision and posterior of random steps: every model variant, body-only, R_eff on and off."""
    model = _models()[index]
    ops = model_operands(model)
    assert ops is not None
    rng = np.random.default_rng(RNG_SEED + 10 * index + (gate is not None))
    n = model.state_dim
    counts = {"accepted": 0, "rejected": 0, "body only": 0}
    for _ in range(60):
        x = rng.standard_normal(n) * 0.01
        x[-1] = rng.uniform(1e3, 1.7e5) if model.stiffness_state == "k_tot" else rng.uniform(-5.0, 5.0)
        if model.stiffness_state == "k_tot":
            x[-1] = min(x[-1], 0.9 * model.k_series)
        m = rng.standard_normal((n, n)) * 1e-2
        P = m @ m.T + np.diag(np.abs(rng.standard_normal(n)) * 1e-4)
        P[-1, -1] = 1e8 if model.stiffness_state == "k_tot" else 0.3
        state = GaussianState(x=x, P=P)
        hdot = rng.standard_normal(int(rng.integers(1, 14))) * 0.05
        u = StepInput(hdot, float(rng.standard_normal())) if rng.random() < 0.5 else hdot
        dt = float(rng.choice([0.01, 0.009999999999999787, 0.002, 0.0107]))
        v_h, v_d = rng.uniform(0.0, 1e-7), rng.uniform(0.0, 1.0)
        c = rng.uniform(-0.9, 0.9) * math.sqrt(v_h * v_d)
        sigma_eps = np.array([[v_h, c], [c, v_d]]) if rng.random() < 0.7 else None
        p = 1 if (model.measurement_dim == 2 and rng.random() < 0.3) else model.measurement_dim
        z = rng.standard_normal(p) * 3.0
        prior, nis, accepted, post = _reference(model, state, u, dt, z, sigma_eps, gate)
        eps = np.zeros((2, 2)) if sigma_eps is None else sigma_eps
        status, x_pred, P_pred, c_nis, c_acc, x_post, P_post = run_ekf_step(
            ops, model, state.x, state.P, u, dt, z, eps, sigma_eps is not None, gate
        )
        assert status == STATUS_OK
        assert _close(x_pred, prior.x, STEP_RTOL) and _cov_close(P_pred, prior.P, STEP_RTOL)
        assert c_acc == accepted
        assert math.isclose(c_nis, nis, rel_tol=STEP_RTOL, abs_tol=1e-12)
        assert _close(x_post, post.x, STEP_RTOL) and _cov_close(P_post, post.P, STEP_RTOL)
        counts["accepted" if accepted else "rejected"] += 1
        counts["body only"] += p < model.measurement_dim
        # Predict-only: the prior alone.
        status, x_pred, P_pred, c_nis, c_acc, *_ = run_ekf_step(
            ops, model, state.x, state.P, u, dt, None, eps, False, gate
        )
        assert status == STATUS_OK and not c_acc and c_nis == 0.0
        assert _close(x_pred, prior.x, STEP_RTOL) and _cov_close(P_pred, prior.P, STEP_RTOL)
    assert counts["accepted"] > 0
    assert gate is None or counts["rejected"] > 0
    assert model.measurement_dim == 1 or counts["body only"] > 0


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_compiled_step_fails_where_the_filter_raises() -> None:
    """A mean that overflows and an R_eff that is not positive definite fail the step, as the public methods raise."""
    model = QuarterCarModel()
    ops = model_operands(model)
    assert ops is not None
    filt = ExtendedKalmanFilter()
    P = np.diag([1e-4, 1e-2, 1e-4, 1e-2, 1e8])
    state = filt.initial_state(np.array([1.5e308, 1.5e308, 1.5e308, 1.5e308, 8e4]), P)
    u = np.full(10, 1e300)
    with pytest.raises(ValueError, match="non-finite"):
        filt.predict(state, model, u, 0.01)
    none = np.zeros((2, 2))
    assert run_ekf_step(ops, model, state.x, state.P, u, 0.01, np.zeros(2), none, False, None)[0] == STATUS_FAILED
    good = filt.initial_state(np.array([0.0, 0.0, 0.0, 0.0, 8e4]), P)
    indefinite = np.array([[-1.0, 0.0], [0.0, 0.0]])
    args = (ops, model, good.x, good.P, np.zeros(10), 0.01, np.zeros(2), indefinite)
    assert run_ekf_step(*args, True, None)[0] == STATUS_FAILED
    assert run_ekf_step(*args, False, None)[0] == STATUS_OK


def _ride(vehicle: str, seconds: float) -> Any:
    from vehicle_sim.plants.quarter_car import LRVVehicle, QuarterCarVehicle, Scenario, SpeedProfile, simulate
    from vehicle_sim.terrain.profiles import iso8608_profile
    from vehicle_sim.terrain.soils import SoilPath, soil_by_name

    lrv = vehicle == "lrv"
    scenario = Scenario(
        profile=iso8608_profile("G" if lrv else "D", 7),
        soil_path=SoilPath([(0.0, soil_by_name("lunar_regolith" if lrv else "graneville_loam"))]),
        speed=SpeedProfile.constant(2.0 if lrv else 10.0),
    )
    return simulate(LRVVehicle() if lrv else QuarterCarVehicle(), scenario, seconds, seed=11)


def _feed(est: SoilStiffnessEstimator, sim: Any) -> list[SoilStiffnessEstimate]:
    pt, ps, ph = (a.tolist() for a in (sim.profile.t, sim.profile.distance, sim.profile.elevation))
    wheel = sim.wheel_accel_z.tolist() if sim.wheel_accel_z is not None else [None] * len(sim.t)
    out: list[SoilStiffnessEstimate] = []
    j = 0
    for i, t in enumerate(sim.t.tolist()):
        while j < len(pt) and pt[j] <= t + 1e-9:
            est.add_profile_sample(pt[j], ps[j], ph[j])
            j += 1
        est.add_accelerations(t, float(sim.body_accel_z[i]), wheel[i])
        out += est.drain_estimates()
    return out


def _assert_same_estimates(got: list[Any], want: list[Any], rtol: float = RIDE_RTOL) -> None:
    """Two estimate streams equal to rounding: states and variances against their largest magnitude."""
    assert len(got) == len(want) > 100
    for field in ("state", "k_s", "k_s_variance", "k_tot", "k_tot_variance", "nis"):
        a = np.array([getattr(e, field) for e in got], dtype=float)
        b = np.array([getattr(e, field) for e in want], dtype=float)
        scale = np.maximum(np.max(np.abs(b), axis=0), 1e-300)
        worst = float(np.max(np.abs(a - b) / scale))
        assert worst <= rtol, f"{field}: relative difference {worst:.3g}"
    for field in ("t", "accepted", "terrain_class", "soil_change_detected", "converged"):
        assert [getattr(e, field) for e in got] == [getattr(e, field) for e in want], field


_RIDE_VARIANTS = [
    SoilStiffnessEstimatorConfig(filter="ekf", quarter_car=QuarterCarParams(stiffness_state="k_tot")),
    SoilStiffnessEstimatorConfig(filter="ekf", quarter_car=QuarterCarParams(stiffness_state="log_k_s")),
    SoilStiffnessEstimatorConfig(filter="ekf", quarter_car=QuarterCarParams(ktot_noise_form="printed")),
    SoilStiffnessEstimatorConfig(filter="ekf", quarter_car=QuarterCarParams(ekf_jacobian="paper")),
    SoilStiffnessEstimatorConfig(
        filter="ekf", quarter_car=QuarterCarParams(ekf_jacobian="paper", stiffness_state="log_k_s")
    ),
    SoilStiffnessEstimatorConfig(vehicle="lrv", filter="ekf", lrv=LRVParams(stiffness_state="k_tot")),
    SoilStiffnessEstimatorConfig(
        vehicle="lrv", filter="ekf", lrv=LRVParams(stiffness_state="k_tot", ekf_jacobian="paper")
    ),
    SoilStiffnessEstimatorConfig(
        vehicle="lrv",
        filter="ekf",
        lrv=LRVParams(stiffness_state="k_tot", relative_damper=False, ktot_noise_form="printed"),
    ),
]


@pytest.mark.parametrize("index", range(len(_RIDE_VARIANTS)))
def test_a_simulated_ride_gives_the_same_estimates_on_both_paths(index: int) -> None:
    """Every Jacobian / noise / stiffness-state variant over 4 s of a simulated ride, estimator default settings."""
    config = _RIDE_VARIANTS[index]
    sim = _ride(config.vehicle, 4.0)
    fast = SoilStiffnessEstimator(config)
    slow = SoilStiffnessEstimator(config, compiled=False)
    assert fast._ekf is not None and slow._ekf is None  # the default is the compiled step
    _assert_same_estimates(_feed(fast, sim), _feed(slow, sim))
    assert fast.counters == slow.counters


@pytest.mark.parametrize(
    ("bag", "vehicle"), [("quarter_car_graneville_iso_d_10ms", "quarter_car"), ("lrv_regolith_iso_g_2ms", "lrv")]
)
def test_a_recorded_bag_gives_the_same_estimates_on_both_paths(bag: str, vehicle: str) -> None:
    """terrain-estimate's path (adapter, node parameters, filter.type = ekf) over a shipped bag, compiled and numpy."""
    from terrain_estimation.tools.estimate import estimate_bag

    topic = f"/{vehicle}/soil_stiffness"
    runs = []
    for compiled in (True, False):
        previous = set_compiled_steps(("sckf", "ekf") if compiled else ())
        try:
            runs.append(estimate_bag(BAGS / bag, vehicle, overrides={"filter.type": "ekf"}))
        finally:
            set_compiled_steps(previous)
    got, want = (run.messages(topic) for run in runs)
    assert len(got) == len(want) > 300
    for name in ("k_s", "k_s_variance", "k_tot", "k_tot_variance", "nis"):
        a = np.array([getattr(m, name) for m in got])
        b = np.array([getattr(m, name) for m in want])
        worst = float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))
        assert worst <= RIDE_RTOL, f"{name}: relative difference {worst:.3g}"


def test_the_estimator_runs_the_compiled_step_by_default_and_expm_keeps_the_public_methods() -> None:
    ekf = SoilStiffnessEstimatorConfig(filter="ekf")
    assert SoilStiffnessEstimator(ekf)._ekf is not None
    assert SoilStiffnessEstimator(ekf, compiled=False)._ekf is None
    assert SoilStiffnessEstimator(ekf, filter_impl=ExtendedKalmanFilter())._ekf is None
    expm = SoilStiffnessEstimatorConfig(filter="ekf", quarter_car=QuarterCarParams(discretisation="expm"))
    assert SoilStiffnessEstimator(expm)._ekf is None
    previous = set_compiled_steps({"sckf"})
    try:
        assert SoilStiffnessEstimator(ekf)._ekf is None and SoilStiffnessEstimator(ekf, compiled=True)._ekf is not None
        assert SoilStiffnessEstimator()._sckf is not None
    finally:
        set_compiled_steps(previous)
    with pytest.raises(ValueError, match="no compiled step"):
        set_compiled_steps({"ukf"})
    assert len(ekf_step.signatures) == 1
