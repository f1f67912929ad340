"""The skid-steer estimator's fast paths give the numbers of the plain forms, bit for bit.

The per-IMU-sample cost of the skid-steer adapter (AN-STUKF step, derived
outputs, output messages) was cut by: the UKF's propagate / measurement
moments / update split into checked public methods around private cores that
the AN-STUKF step calls once its arguments are checked; the Cholesky factor
through numpy's gufunc without np.linalg's wrapper; the observer model's forces
with the x and y quantities stacked and signs folded into constants, the
per-input terms in scalars, the tire sideslip with the wheel positions kept;
the estimator calling the step's checked core, converting the IMU sample at
once and building the estimate's derived outputs on the state's floats; the
output messages built by filling their slots. Each is meant to reproduce the
former computation bit for bit; these tests hold them to it
(``np.array_equal`` / ``==``, never a tolerance) against the straightforward
forms they replaced, written out here.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig
from terrain_estimation.estimators.skid_steer_consider import ConsiderConfig
from terrain_estimation.estimators.skid_steer_estimate import body_sideslip_variance
from terrain_estimation.filters.adaptive import StrongTrackingConfig, suboptimal_fading_factor
from terrain_estimation.filters.an_stukf import AdaptiveStrongTrackingUKF
from terrain_estimation.filters.base import GaussianState, nis_gate
from terrain_estimation.filters.kalman import symmetrise, whiten_innovation
from terrain_estimation.filters.sigma_points import cholesky, robust_sqrt, solve_lower, tria
from terrain_estimation.filters.ukf import UnscentedKalmanFilter
from terrain_estimation.models.skid_steer import SkidSteerParams, quasi_static_loads, tire_sideslip_angles
from terrain_estimation.models.skid_steer_observer import SkidSteerInput, SkidSteerObserverModel, tire_sideslips

RNG_SEED = 20261126
BAG = Path(__file__).resolve().parents[1] / "bags" / "skid_steer_s_shape"


# -- the former forms ---------------------------------------------------------------------------


def _propagate_reference(ukf: UnscentedKalmanFilter, x, P, L, model, u, dt):
    ps = ukf.point_set(x.shape[0])
    X = x + ps.unit @ _robust_sqrt_reference(P).T
    Xp = np.asarray(model.f(X, u, dt), dtype=float)
    x_new = ps.Wm @ Xp
    D = Xp - x_new
    return x_new, symmetrise((D.T * ps.Wc) @ D), L @ L.T


def _moments_reference(ukf: UnscentedKalmanFilter, x, P, Rs, model, u):
    ps = ukf.point_set(x.shape[0])
    dX = ps.unit @ _robust_sqrt_reference(P).T
    Z = np.asarray(model.h(x + dX, u), dtype=float)
    z_hat = ps.Wm @ Z
    dZ_w = (Z - z_hat).T * ps.Wc
    R = Rs @ Rs.T
    return z_hat, symmetrise(dZ_w @ (Z - z_hat) + R), (dZ_w @ dX).T, R


def _update_reference(ukf: UnscentedKalmanFilter, x, P, z, z_hat, P_zz, P_xz):
    nu = z - z_hat
    _, Y, w, nis = _whiten_reference(P_zz, P_xz, nu)
    if not nis_gate(nis, ukf.gate_threshold):
        return x, P, nu, nis, False
    return x + Y.T @ w, symmetrise(P - Y.T @ Y), nu, nis, True


def _step_reference(filt: AdaptiveStrongTrackingUKF, state, z, model, u, dt, memory):
    """AdaptiveStrongTrackingUKF.step as it was composed: propagate, adapt, moments, fading, update."""
    ukf = filt.ukf
    x = np.asarray(state.x, dtype=float)
    P = np.asarray(state.P, dtype=float)
    Lq0 = model.process_noise_sqrt(x, u, dt)
    Rs0 = model.measurement_noise_sqrt()
    x_bar, P0, Q = _propagate_reference(ukf, x, P, Lq0, model, u, dt)
    if filt.variant == "ukf":
        P_prior = symmetrise(1.0 * P0 + Q)
        z_hat, P_zz, P_xz, _ = _moments_reference(ukf, x_bar, P_prior, Rs0, model, u)
        xp, Pp, nu, nis, ok = _update_reference(ukf, x_bar, P_prior, z, z_hat, P_zz, P_xz)
        return xp, Pp, (1.0, 1.0, 0.0, nis, nu, P_zz, ok, memory)
    Rs, scale, a_bar = Rs0, 1.0, 0.0
    if filt.variant == "an_stukf":
        alpha = tire_sideslips(x_bar, model.params)
        a_bar = float(np.abs(alpha).sum() / alpha.size)
        scale = 1.0 + filt.k_q * a_bar
        Lq = Lq0 * math.sqrt(scale)
        Rs = Rs0 / math.sqrt(1.0 + filt.k_r * a_bar)
        Q = Lq @ Lq.T
    P_prior = symmetrise(1.0 * P0 + Q)
    z_hat, P_zz, P_xz, R = _moments_reference(ukf, x_bar, P_prior, Rs, model, u)
    lam, V = suboptimal_fading_factor(z - z_hat, P_zz, P_xz, P_prior, R, Q, memory, filt.strong_tracking)
    if lam != 1.0:
        P_prior = symmetrise(lam * P0 + Q)
        z_hat, P_zz, P_xz, _ = _moments_reference(ukf, x_bar, P_prior, Rs, model, u)
    xp, Pp, nu, nis, ok = _update_reference(ukf, x_bar, P_prior, z, z_hat, P_zz, P_xz)
    return xp, Pp, (lam, scale, a_bar, nis, nu, P_zz, ok, V)


def _f_reference(model: SkidSteerObserverModel, x, u, dt):
    p = model.params
    n = model.substep_count(u, dt)
    delta = dt / n
    xs = np.asarray(x, dtype=float)
    vx, vy, r = xs[..., 0], xs[..., 1], xs[..., 2]
    for _ in range(n):
        fx, fy, mz = model.reference_forces(np.stack([vx, vy, r], axis=-1), u)
        vx, vy, r = (
            vx + delta * (fx / p.mass + vy * r),
            vy + delta * (fy / p.mass - vx * r),
            r + delta * mz / p.yaw_inertia,
        )
    return np.stack([vx, vy, r], axis=-1)


def _h_reference(model: SkidSteerObserverModel, x, u):
    xs = np.asarray(x, dtype=float)
    fx, fy, _ = model.reference_forces(xs, u)
    return np.stack([fx / model.params.mass, fy / model.params.mass, xs[..., 2]], axis=-1)


# -- cases ---------------------------------------------------------------------------------------


def _random_spd(rng: np.random.Generator, n: int) -> np.ndarray:
    A = rng.normal(size=(n, n)) * 10.0 ** rng.uniform(-4, 1, size=n)
    return A @ A.T + 10.0 ** rng.uniform(-12, -2) * np.eye(n)


def _inputs(rng: np.random.Generator, k: int) -> SkidSteerInput:
    """Driving, braking, reversing, standstill (many sub-steps), wheel lift-off, set friction."""
    wl, wr = rng.normal(0.0, 30.0, size=2) if k % 5 else (0.0, 0.0)
    ax, ay = rng.normal(0.0, 3.0 if k % 7 else 40.0, size=2)
    friction = None if k % 2 else float(rng.uniform(0.2, 1.0))
    return SkidSteerInput(float(wl), float(wr), float(ax), float(ay), friction)


def _filter_cases(n: int = 150):
    """(filter, state, z, u, dt, memory): large and small innovations, fading on and off, gating."""
    rng = np.random.default_rng(RNG_SEED)
    filters = [
        AdaptiveStrongTrackingUKF(variant="an_stukf"),
        AdaptiveStrongTrackingUKF(variant="stukf", strong_tracking=StrongTrackingConfig(gamma_th=None)),
        AdaptiveStrongTrackingUKF(variant="ukf", ukf=UnscentedKalmanFilter(gate_threshold=5.0)),
        AdaptiveStrongTrackingUKF(
            variant="an_stukf",
            ukf=UnscentedKalmanFilter(alpha=0.6, kappa=1.0, gate_threshold=8.0),
            strong_tracking=StrongTrackingConfig(gamma_th=1.0, simplified=True, lambda_max=4.0),
        ),
    ]
    for k in range(n):
        u = _inputs(rng, k)
        x = rng.normal([2.0, 0.0, 0.0], [2.0, 0.3, 0.5])
        P = np.diag(rng.uniform(1e-6, 1e-2, size=3))
        z = rng.normal([0.0, 0.0, x[2]], [1.0, 1.0, 0.05]) * (1.0 if k % 3 else 10.0)
        memory = None if k % 4 == 0 else np.diag(rng.uniform(0.0, 2.0, size=3))
        yield filters[k % len(filters)], GaussianState(x=x, P=P), z, u, float(rng.uniform(0.005, 0.02)), memory


# -- filters ---------------------------------------------------------------------------------------


def _robust_sqrt_reference(P):
    """robust_sqrt as first written: np.linalg.cholesky, else the PSD projection."""
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(0.5 * (P + P.T))
        return tria(V * np.sqrt(np.clip(w, 0.0, None)))


def _whiten_reference(P_zz, P_xz, nu):
    """whiten_innovation as first written: np.linalg.cholesky and np.column_stack."""
    n = P_xz.shape[0]
    try:
        L = np.linalg.cholesky(P_zz)
    except np.linalg.LinAlgError:
        p = P_zz.shape[0]
        nan = np.full((p, p + n + 1), np.nan)
        return nan[:, :p], nan[:, p : p + n], nan[:, p + n], float("inf")
    sol = solve_lower(L, np.column_stack([P_xz.T, nu]))
    return L, sol[:, :n], sol[:, n], float(sol[:, n] @ sol[:, n])


def test_cholesky_is_numpys_bit_for_bit_and_fails_the_same_way():
    rng = np.random.default_rng(RNG_SEED)
    for n in (1, 2, 3, 5):
        for _ in range(200):
            P = _random_spd(rng, n)
            assert np.array_equal(cholesky(P), np.linalg.cholesky(P))
            assert np.array_equal(robust_sqrt(P), _robust_sqrt_reference(P))
    # Other dtypes go through np.linalg (its casts): the same result and dtype.
    P32 = _random_spd(rng, 3).astype(np.float32)
    assert cholesky(P32).dtype == np.float32 and np.array_equal(cholesky(P32), np.linalg.cholesky(P32))
    # Not positive definite: LinAlgError where np.linalg raises, and the PSD projection for the points;
    # NaN: whatever np.linalg gives (here a NaN factor, LAPACK's comparison does not see it).
    for bad in (np.diag([1.0, -1e-12, 2.0]), np.zeros((3, 3)), np.ones((3, 3)), np.full((3, 3), np.nan)):
        try:
            expected = np.linalg.cholesky(bad)
        except np.linalg.LinAlgError:
            with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
                cholesky(bad)
            assert np.array_equal(robust_sqrt(bad), _robust_sqrt_reference(bad))
        else:
            assert np.array_equal(cholesky(bad), expected, equal_nan=True)


def test_whitening_is_the_former_whiten_innovation():
    rng = np.random.default_rng(RNG_SEED + 1)
    for _ in range(300):
        P_zz = _random_spd(rng, 3)
        P_xz = rng.normal(size=(3, 3)) * 0.1
        nu = rng.normal(size=3)
        got, ref = whiten_innovation(P_zz, P_xz, nu), _whiten_reference(P_zz, P_xz, nu)
        assert all(np.array_equal(a, b) for a, b in zip(got[:3], ref[:3], strict=True)) and got[3] == ref[3]
    L, Y, w, nis = whiten_innovation(-np.eye(3), np.ones((3, 3)), np.ones(3))
    assert nis == math.inf and np.isnan(L).all() and np.isnan(Y).all() and np.isnan(w).all()


def test_ukf_public_methods_are_the_former_forms():
    model = SkidSteerObserverModel()
    for filt, state, z, u, dt, _ in _filter_cases(60):
        ukf = filt.ukf
        x, P = state.x, state.P
        L = model.process_noise_sqrt(x, u, dt)
        Rs = model.measurement_noise_sqrt()
        pred = ukf.propagate(state, model, u, dt)
        ref = _propagate_reference(ukf, x, P, L, model, u, dt)
        assert all(np.array_equal(a, b) for a, b in zip((pred.x, pred.P0, pred.Q), ref, strict=True))
        prior = pred.state()
        mm = ukf.measurement_moments(prior, model, u)
        ref_mm = _moments_reference(ukf, prior.x, prior.P, Rs, model, u)
        assert all(np.array_equal(a, b) for a, b in zip((mm.z_hat, mm.P_zz, mm.P_xz, mm.R), ref_mm, strict=True))
        post, info = ukf.update(prior, z, model, u)
        xr, Pr, nu, nis, ok = _update_reference(ukf, prior.x, prior.P, z, *ref_mm[:3])
        assert np.array_equal(post.x, xr) and np.array_equal(post.P, Pr)
        assert np.array_equal(info.innovation, nu) and info.nis == nis and info.accepted == ok
        if not ok:
            assert post is prior


def test_an_stukf_step_is_the_former_composition():
    model = SkidSteerObserverModel()
    faded = gated = 0
    for filt, state, z, u, dt, memory in _filter_cases():
        post, res = filt.step(state, z, model, u, dt, memory)
        x_ref, P_ref, (lam, scale, a_bar, nis, nu, P_zz, ok, V) = _step_reference(filt, state, z, model, u, dt, memory)
        assert np.array_equal(post.x, x_ref) and np.array_equal(post.P, P_ref)
        assert (res.fading_factor, res.noise_scale, res.mean_abs_sideslip, res.nis) == (lam, scale, a_bar, nis)
        assert np.array_equal(res.innovation, nu) and np.array_equal(res.innovation_cov, P_zz)
        assert res.accepted == ok
        assert (res.memory is None and V is None) or np.array_equal(res.memory, V)
        faded += lam > 1.0
        gated += not ok
    assert faded > 10 and gated > 5  # both branches of the step were compared


# -- model -----------------------------------------------------------------------------------------


def test_model_f_h_and_forces_are_the_former_forms():
    model = SkidSteerObserverModel()
    rng = np.random.default_rng(RNG_SEED + 2)
    for k in range(150):
        u = _inputs(rng, k)
        dt = float(rng.uniform(0.002, 0.02))
        for shape in ((3,), (7, 3), (2, 5, 3)):
            x = rng.normal([1.0, 0.0, 0.0], [2.0, 0.3, 0.8], size=shape)
            f = model.f(x, u, dt)
            assert f.shape == shape and f.flags.c_contiguous and np.array_equal(f, _f_reference(model, x, u, dt))
            h = model.h(x, u)
            assert h.shape == shape and h.flags.c_contiguous and np.array_equal(h, _h_reference(model, x, u))
            for a, b in zip(model.forces(x, u), model.reference_forces(x, u), strict=True):
                assert type(a) is type(b) and a.shape == shape[:-1] and np.array_equal(a, b)
    with pytest.raises(ValueError, match="shape"):
        model.f(np.zeros((7, 4)), u, 0.01)


def test_noise_factors_are_the_diagonal_matrices():
    model = SkidSteerObserverModel(q0_diag=(1e-4, 2e-4, 3e-6))
    for dt in (0.001, 0.01, 0.0137, 0.1):
        got = model.process_noise_sqrt(np.zeros(3), None, dt)
        expected = np.diag(np.sqrt(np.array([1e-4, 2e-4, 3e-6])) * math.sqrt(dt / 0.01))
        assert got.shape == (3, 3) and got.dtype == expected.dtype and np.array_equal(got, expected)


def test_per_input_terms_are_the_array_forms():
    model = SkidSteerObserverModel()
    p = model.params
    rng = np.random.default_rng(RNG_SEED + 3)
    for k in range(300):
        u = _inputs(rng, k)
        terms = model._terms(u)
        friction = p.friction if u.friction is None else u.friction
        omega_wheel = np.repeat(np.array([u.omega_left, u.omega_right]), 3)
        rolling = p.wheel_radius * omega_wheel
        loads = quasi_static_loads(u.ax, u.ay, p)
        mu_fz = np.asarray(friction, dtype=float) * np.maximum(loads, 0.0)
        limit = 3.0 * mu_fz
        expected = {
            "omega_wheel": omega_wheel,
            "normal_load": loads,
            "rolling": rolling,
            "rolling_floored": np.maximum(np.abs(rolling), p.rolling_speed_floor),
            "mu_fz": mu_fz,
            "limit": limit,
            "limit_divisor": np.where(limit > 0.0, limit, 1.0),
        }
        for name, value in expected.items():
            assert np.array_equal(getattr(terms, name), value), name
        assert terms.friction == friction
        assert terms.min_rolling_speed == max(min(abs(u.omega_left), abs(u.omega_right)) * p.wheel_radius, 0.05)
    # The tire sideslip at one state, the adaptation's input: tire_sideslip_angles of the contact velocities.
    x = np.array([1.2, -0.1, 0.3])
    assert np.array_equal(model.tire_sideslip(x), tire_sideslip_angles(*_contact(x, p)))


def _contact(x: np.ndarray, p: SkidSteerParams) -> tuple[np.ndarray, np.ndarray]:
    from terrain_estimation.models.skid_steer import contact_velocities

    return contact_velocities(x[0], x[1], x[2], p)


# -- estimator ------------------------------------------------------------------------------------


def test_body_sideslip_variance_is_the_array_form():
    rng = np.random.default_rng(RNG_SEED + 4)
    floor_sq = SkidSteerParams().rolling_speed_floor ** 2
    for k in range(20000):
        x = rng.normal(0.0, 10.0 ** rng.uniform(-3, 1), size=3) if k % 10 else np.zeros(3)
        P = _random_spd(rng, 3)
        v2 = max(float(x[0] ** 2 + x[1] ** 2), floor_sq)  # numpy float64 scalars, as before
        jac = np.array([-x[1], x[0]]) / v2
        expected = min(float(jac @ P[:2, :2] @ jac), math.pi**2)
        got_v2, got = body_sideslip_variance(float(x[0]), float(x[1]), P, floor_sq)
        # Scalars against BLAS's (possibly fused) multiply-adds: equal to rounding (of the terms, which
        # cancel on an ill-conditioned P), not bit for bit.
        scale = float(jac @ jac) * float(np.abs(P[:2, :2]).max())
        assert got_v2 == v2 and got == pytest.approx(expected, rel=1e-12, abs=1e-13 * scale)
    # Overflow (a fuzzed input can make the state huge): numpy's float64 ** gives inf, so must this.
    with np.errstate(over="ignore"):
        x = np.array([7e297, 0.0, 0.0])
        v2 = max(float(x[0] ** 2 + x[1] ** 2), floor_sq)
    assert v2 == math.inf
    with np.errstate(over="ignore"):
        assert body_sideslip_variance(7e297, 0.0, np.eye(3), floor_sq) == (math.inf, 0.0)


def test_counter_values_are_the_counters():
    est = SkidSteerEstimator()
    for k in range(1, 30):
        t = 0.01 * k
        est.add_joint_state(t, 60.0, 70.0)
        est.add_imu(t, 0.1, 0.2, 0.05)
    assert dict(est.counter_values()) == dataclasses.asdict(est.counters)
    assert list(est.counter_values()) == [f.name for f in dataclasses.fields(est.counters)]


class _ReferenceFilter:
    """The estimator's filter, stepped by the former composition."""

    def __init__(self, inner: AdaptiveStrongTrackingUKF) -> None:
        self.inner = inner

    def initial_state(self, x0: Any, P0: Any) -> GaussianState:
        return self.inner.initial_state(x0, P0)

    def step(self, state, z, model, u, dt, memory=None):
        from terrain_estimation.filters.an_stukf import AnStukfResult

        x, P, (lam, scale, a_bar, nis, nu, P_zz, ok, V) = _step_reference(self.inner, state, z, model, u, dt, memory)
        res = AnStukfResult(
            fading_factor=float(lam),
            noise_scale=float(scale),
            mean_abs_sideslip=float(a_bar),
            nis=float(nis),
            innovation=nu,
            innovation_cov=P_zz,
            accepted=ok,
            memory=V,
        )
        return GaussianState(x=x, P=P), res


@pytest.mark.parametrize("variant", ["an_stukf", "stukf"])
def test_estimator_on_the_bag_is_the_former_composition(variant: str):
    from terrain_estimation.bag import read_bag
    from terrain_estimation.ros.time import stamp_to_ns

    items = list(read_bag(BAG, ["/skid_steer/imu", "/skid_steer/joint_states"]))[:800]
    # The consider covariance needs the update's moments, which the former composition did not report.
    config = SkidSteerEstimatorConfig(
        filter=variant, strong_tracking=StrongTrackingConfig(gamma_th=1.0), consider=ConsiderConfig(parameters=())
    )
    fast, ref = SkidSteerEstimator(config), SkidSteerEstimator(config)
    ref.filter = _ReferenceFilter(ref.filter)  # type: ignore[assignment]
    for n, item in enumerate(items):
        m = item.msg
        t = stamp_to_ns(m.header.stamp) * 1e-9
        for est in (fast, ref):
            if item.topic.endswith("imu"):
                kick = 0.4 * (n % 5)  # innovations large enough for strong tracking now and then
                est.add_imu(t, m.linear_acceleration.x + kick, m.linear_acceleration.y, m.angular_velocity.z)
            else:
                est.add_joint_state(t, m.velocity[0], m.velocity[1])
    a, b = fast.drain_estimates(), ref.drain_estimates()
    assert len(a) == len(b) > 300
    assert a == b  # every field (floats compared with ==)
    assert any(e.fading_factor > 1.0 for e in a)


# -- messages ---------------------------------------------------------------------------------------


def _canonical(value: Any) -> Any:
    """Every field of a message, recursively, with types, float bits and array bytes."""
    if hasattr(value, "get_fields_and_field_types"):
        fields = tuple((k, _canonical(getattr(value, k))) for k in value.get_fields_and_field_types())
        return type(value).__name__, value._check_fields, fields
    if isinstance(value, np.ndarray):
        return "ndarray", value.dtype.str, value.shape, value.flags.c_contiguous, value.tobytes()
    if isinstance(value, float):
        return type(value).__name__, value.hex()
    return type(value).__name__, repr(value)


def _adapter_outputs(monkeypatch: pytest.MonkeyPatch, fast: bool) -> list[tuple[str, Any]]:
    import terrain_estimation.ros.skid_steer as ros_skid_steer
    from terrain_estimation.bag import read_bag
    from terrain_estimation.tools.estimate import estimator_parameters, get_vehicle, topic_name

    monkeypatch.setattr(ros_skid_steer, "_FAST_MESSAGES", fast)
    entry = get_vehicle("skid_steer")
    values = estimator_parameters(entry, None, None)
    adapter = entry.make_adapter(values, entry.namespace)
    keys = {topic_name(entry.namespace, s.topic): s.key for s in adapter.inputs}
    out: list[tuple[str, Any]] = []
    for item in list(read_bag(BAG, list(keys)))[:300]:
        out.extend(adapter.handle(keys[item.topic], item.msg))
    return out


def test_output_messages_are_the_constructors_messages(monkeypatch: pytest.MonkeyPatch):
    from rclpy.serialization import deserialize_message, serialize_message

    import terrain_estimation.ros.skid_steer as ros_skid_steer

    assert ros_skid_steer._FAST_MESSAGES  # the slot-filling builders are what runs here
    fast = _adapter_outputs(monkeypatch, True)
    plain = _adapter_outputs(monkeypatch, False)
    assert len(fast) == len(plain) > 200
    for (key_a, a), (key_b, b) in zip(fast, plain, strict=True):
        assert key_a == key_b and type(a) is type(b)
        assert a == b and _canonical(a) == _canonical(b)
        # Serialisable, and what comes back is the message (the CDR padding bytes are not defined).
        assert _canonical(deserialize_message(serialize_message(a), type(a))) == _canonical(b)
    # The public builders take the same path.
    e = SkidSteerEstimator()
    for k in range(1, 20):
        e.add_joint_state(0.01 * k, 60.0, 70.0)
        e.add_imu(0.01 * k, 0.1, 0.2, 0.05)
    last = e.last_estimate
    assert last is not None
    built = (ros_skid_steer.estimate_to_odom_msg(last, "o", "b"), ros_skid_steer.estimate_to_state_msg(last, "b"))
    monkeypatch.setattr(ros_skid_steer, "_FAST_MESSAGES", False)
    plain_built = (ros_skid_steer.estimate_to_odom_msg(last, "o", "b"), ros_skid_steer.estimate_to_state_msg(last, "b"))
    assert [_canonical(m) for m in built] == [_canonical(m) for m in plain_built]


def test_fast_messages_only_where_they_match_the_constructors(monkeypatch: pytest.MonkeyPatch):
    import sys

    from nav_msgs.msg import Odometry

    import terrain_estimation.ros.skid_steer as ros_skid_steer

    assert ros_skid_steer._fast_messages_apply()
    # A message definition with other fields: the constructors.
    slots = dict(ros_skid_steer._SLOTS)
    slots[Odometry] = ("_header", "_pose", "_twist")
    monkeypatch.setattr(ros_skid_steer, "_SLOTS", slots)
    assert not ros_skid_steer._fast_messages_apply()
    monkeypatch.undo()
    # rclpy checking fields (ROS_PYTHON_CHECK_FIELDS=1 when the messages were imported): the constructors.
    monkeypatch.setattr(sys.modules[Odometry.__module__], "ros_python_check_fields", "1")
    assert not ros_skid_steer._fast_messages_apply()


@pytest.mark.parametrize(
    "args",
    [
        (math.nan, math.inf, 0.0, 0.0),
        (1.0, math.inf, math.nan, 0.0),
        (1.0, 0.0, "x", math.nan),
        (1.0, None, 0.0, 0.0),
        (1.0, 0.0, 0.0, -math.inf),
    ],
)
def test_imu_argument_errors_name_the_first_offending_argument(args: tuple[Any, ...]):
    """add_imu converts its four arguments at once; a bad one raises what checking them in order raises."""
    from terrain_estimation.estimators.skid_steer import _finite

    with pytest.raises((TypeError, ValueError)) as expected:
        for name, value in zip(("t", "ax", "ay", "yaw_rate"), args, strict=True):
            _finite("add_imu", name, value)
    est = SkidSteerEstimator()
    with pytest.raises(expected.type, match=re.escape(str(expected.value))):
        est.add_imu(*args)
    assert est.counters.imu_samples == 0
