"""The compiled SCKF step (``estimators.soil_stiffness_sckf``) is the SCKF of the public methods.

The reference is :class:`~terrain_estimation.filters.sckf.SquareRootCubatureKalmanFilter`'s
``predict``/``update`` with the model's own ``f``, ``h`` and noise factors
(themselves held to the SCKF as first written in
``test_soil_stiffness_fast_paths.py``). The compiled step writes the QR and
the small products out, so the comparison is to rounding, not bit for bit.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from typing import Any

import numpy as np
import pytest

from terrain_estimation.estimators.soil_stiffness import (
    SoilStiffnessEstimator,
    SoilStiffnessEstimatorConfig,
    _BodyOnly,
)
from terrain_estimation.estimators.soil_stiffness_sckf import (
    STATUS_FAILED,
    STATUS_OK,
    model_operands,
    run_step,
    sckf_step,
)
from terrain_estimation.filters.compiled_linalg import cholesky_lower as _cholesky_lower
from terrain_estimation.filters.compiled_linalg import solve_lower as _solve_lower
from terrain_estimation.filters.compiled_linalg import tria as _tria
from terrain_estimation.filters.sckf import SquareRootCubatureKalmanFilter
from terrain_estimation.filters.sigma_points import solve_lower, tria
from terrain_estimation.models.quarter_car import (
    LRVModel,
    LRVParams,
    QuarterCarModel,
    QuarterCarParams,
    StepInput,
)

RNG_SEED = 20261126 + 500
RTOL = 1e-9


def _models() -> list[Any]:
    return [
        QuarterCarModel(QuarterCarParams(stiffness_state="k_tot")),
        QuarterCarModel(QuarterCarParams(stiffness_state="log_k_s")),
        QuarterCarModel(QuarterCarParams(ktot_noise_form="printed")),
        LRVModel(LRVParams(relative_damper=True, stiffness_state="log_k_s")),
        LRVModel(LRVParams(relative_damper=False, stiffness_state="k_tot")),
    ]


def _close(got: np.ndarray, want: np.ndarray, scale: np.ndarray | float | None = None) -> bool:
    """Equal to rounding: ``|got − want| ≤ RTOL · scale`` (default the size of ``want``)."""
    got, want = np.asarray(got), np.asarray(want)
    if scale is None:
        scale = max(float(np.max(np.abs(want))), 1e-300)
    return bool(np.all(np.abs(got - want) <= RTOL * np.asarray(scale)))


def _factor_close(got: np.ndarray, want: np.ndarray) -> bool:
    """Two lower factors: the same covariance, to rounding, entry by entry on the diagonal's scale."""
    d = np.sqrt(np.abs(np.diag(want @ want.T)))
    scale = np.maximum(np.outer(d, d), 1e-300)
    return _close(got @ got.T, want @ want.T, scale) and np.allclose(np.triu(got, 1), 0.0)


def _random_case(model: Any, rng: np.random.Generator) -> tuple[Any, ...]:
    n = model.state_dim
    x = rng.standard_normal(n) * 0.01
    x[-1] = rng.uniform(1e3, 1.7e5) if model.stiffness_state == "k_tot" else rng.uniform(-5.0, 5.0)
    p0 = np.diag(np.abs(rng.standard_normal(n)) * 1e-4)
    p0[-1, -1] = 1e8 if model.stiffness_state == "k_tot" else 0.3
    state = SquareRootCubatureKalmanFilter().initial_state(x, p0)
    hdot = rng.standard_normal(int(rng.integers(1, 14))) * 0.05
    u = StepInput(hdot, float(rng.standard_normal())) if rng.random() < 0.5 else hdot
    dt = float(rng.choice([0.01, 0.009999999999999787, 0.002, 0.0107]))
    v_h = rng.uniform(0.0, 1e-7)
    v_d = rng.uniform(0.0, 1.0)
    cov = rng.uniform(-0.9, 0.9) * math.sqrt(v_h * v_d)
    sigma_eps = np.array([[v_h, cov], [cov, v_d]])
    return state, u, dt, sigma_eps


def _reference_step(
    model: Any, state: Any, u: Any, dt: float, z: np.ndarray, sigma_eps: np.ndarray, profile_noise: bool, gate: Any
) -> tuple[Any, float, bool, Any]:
    """Predict and update through the public SCKF and the model's methods: ``(prior, nis, accepted, post)``."""
    filt = SquareRootCubatureKalmanFilter(gate_threshold=gate)
    prior = filt.predict(state, model, u, dt)
    p = z.size
    meas = model if p == model.measurement_dim else _BodyOnly(model)
    rs = None
    if profile_noise:
        g_h, g_d = model.profile_error_gains(prior.x)
        gain = np.stack([g_h[:p], g_d[:p]], axis=1)
        r_eff = np.diag(model.measurement_noise_sqrt().diagonal()[:p] ** 2) + gain @ sigma_eps @ gain.T
        rs = np.linalg.cholesky(r_eff)
    post, info = filt.update(prior, z, meas, u, measurement_noise_sqrt=rs)
    return prior, float(info.nis), bool(info.accepted), post


def _compiled_step(
    model: Any,
    state: Any,
    u: Any,
    dt: float,
    z: np.ndarray | None,
    sigma_eps: np.ndarray,
    profile_noise: bool,
    gate: float | None,
) -> tuple[Any, ...]:
    ops = model_operands(model)
    assert ops is not None
    return run_step(ops, model, state.x, state.S, u, dt, z, sigma_eps, profile_noise, gate)


@pytest.mark.parametrize("index", range(5))
@pytest.mark.parametrize("gate", [None, 3.0])
def test_compiled_step_equals_the_public_filter(index: int, gate: float | None) -> None:
    """Prior, NIS, gate decision and posterior of random steps, with and without the profile-noise term."""
    model = _models()[index]
    rng = np.random.default_rng(RNG_SEED + 10 * index + (gate is not None))
    counts = {"accepted": 0, "rejected": 0, "body only": 0}
    for _ in range(80):
        state, u, dt, sigma_eps = _random_case(model, rng)
        p = model.measurement_dim
        if p == 2 and rng.random() < 0.3:
            p = 1  # the wheel accelerometer missing: ÿ1 alone
            counts["body only"] += 1
        z = rng.standard_normal(p) * 3.0
        profile_noise = bool(rng.random() < 0.7)
        prior, nis, accepted, post = _reference_step(model, state, u, dt, z, sigma_eps, profile_noise, gate)
        status, x_pred, S_pred, c_nis, c_accepted, x_post, S_post = _compiled_step(
            model, state, u, dt, z, sigma_eps, profile_noise, gate
        )
        assert status == STATUS_OK
        scale = np.sqrt(np.diag(prior.covariance))
        assert _close(x_pred, prior.x, scale)
        assert _factor_close(S_pred, prior.S)
        assert c_nis == pytest.approx(nis, rel=RTOL)
        assert c_accepted == accepted
        counts["accepted" if accepted else "rejected"] += 1
        assert _close(x_post, post.x, scale)
        assert _factor_close(S_post, post.S)
        # The predict-only step is the same prior.
        status, x_only, S_only, nis0, acc0, x_same, S_same = _compiled_step(
            model, state, u, dt, None, sigma_eps, profile_noise, gate
        )
        assert status == STATUS_OK and nis0 == 0.0 and not acc0
        assert np.array_equal(x_only, x_pred) and np.array_equal(S_only, S_pred)
        assert np.array_equal(x_same, x_only) and np.array_equal(S_same, S_only)
    assert counts["accepted"] > 0
    assert gate is None or counts["rejected"] > 0
    assert model.measurement_dim == 1 or counts["body only"] > 0


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_compiled_step_fails_where_the_filter_raises() -> None:
    """Points that overflow and an R_eff that is not positive definite fail the step, as the public methods raise."""
    model = QuarterCarModel()
    filt = SquareRootCubatureKalmanFilter()
    p0 = np.diag([1e-4, 1e-2, 1e-4, 1e-2, 1e8])
    state = filt.initial_state(np.array([1.5e308, 1.5e308, 1.5e308, 1.5e308, 8e4]), p0)
    u = np.full(10, 1e300)
    with pytest.raises(ValueError, match="non-finite"):
        filt.predict(state, model, u, 0.01)
    none = np.zeros((2, 2))
    assert _compiled_step(model, state, u, 0.01, np.zeros(2), none, False, None)[0] == STATUS_FAILED
    good = filt.initial_state(np.array([0.0, 0.0, 0.0, 0.0, 8e4]), np.diag([1e-4, 1e-2, 1e-4, 1e-2, 1e8]))
    indefinite = np.array([[-1.0, 0.0], [0.0, 0.0]])  # R + G Σ Gᵀ with a huge negative elevation variance
    assert _compiled_step(model, good, np.zeros(10), 0.01, np.zeros(2), indefinite, True, None)[0] == STATUS_FAILED
    assert _compiled_step(model, good, np.zeros(10), 0.01, np.zeros(2), indefinite, False, None)[0] == STATUS_OK


@pytest.mark.parametrize("shape", [(15, 5), (12, 5), (12, 2), (7, 2), (3, 3), (1, 1), (11, 5), (3, 5)])
def test_compiled_tria_is_the_lapack_factor(shape: tuple[int, int]) -> None:
    """The Householder ``tria`` against the LAPACK one: same lower factor (diagonal ≥ 0), to rounding."""
    rng = np.random.default_rng(RNG_SEED + 100 + shape[0] * 31 + shape[1])
    for trial in range(20):
        rows = rng.standard_normal(shape) * 10.0 ** rng.uniform(-6, 6, shape[1])
        if trial == 3:
            rows[:, 0] = 0.0  # a zero column: a zero diagonal entry
        want = tria(rows.T)
        got = _tria(rows.copy())
        assert np.array_equal(got, np.tril(got)) and np.all(np.diag(got) >= 0.0)
        assert np.allclose(got, want, rtol=1e-10, atol=1e-10 * np.max(np.abs(want)))


def test_compiled_solves_and_cholesky() -> None:
    rng = np.random.default_rng(RNG_SEED + 200)
    for p in (1, 2, 5):
        m = rng.standard_normal((p, p + 3))
        spd = m @ m.T + np.eye(p)
        L, ok = _cholesky_lower(spd)
        assert ok and np.allclose(L, np.linalg.cholesky(spd), rtol=1e-12, atol=1e-14)
        B = rng.standard_normal((p, 4))
        for transpose in (False, True):
            assert np.allclose(_solve_lower(L, B, transpose), solve_lower(L, B, transpose=transpose), rtol=1e-12)
    assert not _cholesky_lower(np.array([[1.0, 2.0], [2.0, 1.0]]))[1]
    assert not _cholesky_lower(np.array([[math.nan]]))[1]


def test_expm_discretisation_runs_the_public_methods() -> None:
    """The compiled step implements "taylor4" only: an "expm" model keeps the public predict/update."""
    assert model_operands(QuarterCarModel(QuarterCarParams(discretisation="expm"))) is None
    est = SoilStiffnessEstimator(SoilStiffnessEstimatorConfig(quarter_car=QuarterCarParams(discretisation="expm")))
    assert est._sckf is None
    assert SoilStiffnessEstimator()._sckf is not None


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("vehicle", ["quarter_car", "lrv"])
def test_one_compiled_signature_serves_every_step(vehicle: str) -> None:
    """A stream with gaps, restarts, bad samples and a missing wheel accelerometer compiles nothing more.

    A second specialisation (a read-only or non-contiguous array, an int for
    a float) would stop the node for the compiler in the middle of a run.
    """
    est = SoilStiffnessEstimator(SoilStiffnessEstimatorConfig(vehicle=vehicle))
    rng = np.random.default_rng(RNG_SEED + 300)
    t_acc = 0.0
    speed = 2.0 if vehicle == "lrv" else 10.0
    for i in range(1, 3000):
        t = i * 1e-3
        if not 1.2 < t < 1.26:
            h = 0.01 * math.sin(7.0 * t) + (math.nan if i % 701 == 0 else 1e-4 * rng.standard_normal())
            est.add_profile_sample(t, speed * t, h)
        if t - t_acc >= 0.01 and not 2.0 < t < 2.6:
            t_acc = t
            wheel = None if i % 13 == 0 else 9.8 + 20.0 * math.sin(41.0 * t)
            est.add_accelerations(t, 9.8 + math.sin(7.0 * t) + (1e300 if i % 997 == 0 else 0.0), wheel)
    c = est.counters
    assert c.updates_accepted > 20 and c.predict_only > 0 and c.restarts > 0
    assert len(sckf_step.signatures) == 1


def test_the_estimator_compiles_its_step_when_it_is_built() -> None:
    """Built, before any sample: the step is compiled (or loaded from numba's cache), so a node's first
    filter step does not wait for the compiler. In a fresh process, where nothing else compiled it."""
    code = (
        "from terrain_estimation.estimators.soil_stiffness import SoilStiffnessEstimator\n"
        "from terrain_estimation.estimators.soil_stiffness_sckf import sckf_step\n"
        "assert not sckf_step.signatures\n"
        "SoilStiffnessEstimator()\n"
        "print(len(sckf_step.signatures))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.split() == ["1"]


def test_without_a_place_for_numbas_cache_the_step_still_compiles() -> None:
    """A read-only install and home (no cache locator): the imports of every numba user warn once in all,
    and the estimator still runs (``terrain_estimation.jit``)."""
    code = (
        "import warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    from terrain_estimation.estimators.soil_stiffness import SoilStiffnessEstimator\n"
        "    import terrain_analysis.sim2real.quarter_car, terrain_analysis.sim2real.single_wheel\n"
        "    import terrain_analysis.sim2real.skid_steer\n"
        "from terrain_estimation.estimators.soil_stiffness_sckf import sckf_step\n"
        "notes = [str(w.message) for w in caught if 'NUMBA_CACHE_DIR' in str(w.message)]\n"
        "est = SoilStiffnessEstimator()\n"
        "for i in range(1, 60):\n"
        "    est.add_profile_sample(i * 1e-3, i * 1e-2, 0.0)\n"
        "est.add_accelerations(0.02, 9.8, 9.8)\n"
        "est.add_accelerations(0.04, 9.8, 9.8)\n"
        "print(len(notes), len(sckf_step.signatures), est.counters.steps)\n"
    )
    env = dict(os.environ, NUMBA_CACHE_LOCATOR_CLASSES="ZipCacheLocator")  # finds no place for a .py module
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env, check=True)
    notes, signatures, steps = (int(v) for v in out.stdout.split())
    assert notes == 1 and signatures == 1 and steps >= 1
