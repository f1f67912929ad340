"""The compiled skid-steer filter step gives the estimates of the Python step (to rounding).

:mod:`terrain_estimation.estimators.skid_steer_compiled` runs the "adaptive" filter step over the brush
models and the consider-covariance step in one numba call; the Python step
(:meth:`AdaptiveStrongTrackingUKF._step`, :meth:`ConsiderCovariance.step`) stays the reference
(``estimate_bag(..., reference=True)``, ``SkidSteerEstimator.use_compiled = False``). The two use
different summation orders (loops here, BLAS and LAPACK there), so they agree to rounding, not bit for
bit: these tests hold every published number of the shipped bags to 1e-9 of its field's scale, and
check that the compiled step really ran (and hands back the steps it cannot reproduce).
"""

# ruff: noqa: N806 - matrix symbols

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig
from terrain_estimation.estimators.skid_steer_compiled import STATUS_FALLBACK, STATUS_OK
from terrain_estimation.estimators.skid_steer_consider import ConsiderConfig
from terrain_estimation.filters.noise_adaptation import InnovationNoiseConfig
from terrain_estimation.models.skid_steer_scales import TireScaleConfig

BAGS = Path(__file__).resolve().parents[1] / "bags"
RTOL = 1e-9


def _numbers(msg: Any, prefix: str = "") -> dict[str, float]:
    """Every numeric scalar and array element of a message (header stamps included), by path."""
    out: dict[str, float] = {}
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        path = f"{prefix}{name}"
        if hasattr(value, "get_fields_and_field_types"):
            out.update(_numbers(value, path + "."))
        elif isinstance(value, (bool, int, float)):
            out[path] = float(value)
        elif isinstance(value, (np.ndarray, list, tuple)) and not isinstance(value, str):
            for i, v in enumerate(value):
                if isinstance(v, (bool, int, float, np.floating)):
                    out[f"{path}[{i}]"] = float(v)
    return out


def _assert_same_messages(a: list[tuple[str, Any, int]], b: list[tuple[str, Any, int]]) -> None:
    """Every number of every message within ``RTOL`` of its scale: the field's largest magnitude over the
    run; for an entry ``(i, j)`` of a 6×6 covariance, ``√(max P_ii · max P_jj)`` (a correlation's scale:
    the off-diagonal entries are differences of products of the variances' size)."""
    assert [(t, n) for t, _, n in a] == [(t, n) for t, _, n in b]
    topics = sorted({t for t, _, _ in a})
    for topic in topics:
        rows_a = [_numbers(m) for t, m, _ in a if t == topic]
        rows_b = [_numbers(m) for t, m, _ in b if t == topic]
        peak = {f: float(np.max(np.abs([r[f] for r in rows_a]))) for f in rows_a[0]}
        for field in rows_a[0]:
            x = np.array([r[field] for r in rows_a])
            y = np.array([r[field] for r in rows_b])
            scale = peak[field]
            if field.endswith("]") and ".covariance[" in field:
                head, index = field[:-1].split("[")
                i, j = divmod(int(index), 6)
                scale = max(scale, float(np.sqrt(peak[f"{head}[{7 * i}]"] * peak[f"{head}[{7 * j}]"])))
            worst = float(np.max(np.abs(x - y)))
            assert worst <= RTOL * scale, f"{topic} {field}: differs by {worst:.3g} (scale {scale:.3g})"


@pytest.mark.parametrize("bag", ["skid_steer_s_shape", "skid_steer_small_radius_turn"])
def test_shipped_bag_estimates_are_the_python_steps(bag: str) -> None:
    from terrain_estimation.tools.estimate import estimate_bag

    new = estimate_bag(BAGS / bag, "skid_steer")
    ref = estimate_bag(BAGS / bag, "skid_steer", reference=True)
    assert len(new.outputs) == len(ref.outputs) > 1000
    _assert_same_messages(new.outputs, ref.outputs)


def _feed(est: SkidSteerEstimator, bag: str, kick: float = 0.0) -> list[Any]:
    from terrain_estimation.bag import read_bag
    from terrain_estimation.ros.time import stamp_to_ns

    for n, item in enumerate(read_bag(BAGS / bag, ["/skid_steer/imu", "/skid_steer/joint_states"])):
        m = item.msg
        t = stamp_to_ns(m.header.stamp) * 1e-9
        if item.topic.endswith("imu"):
            # every fifth sample pushed: innovations large enough for strong tracking (λ > 1) now and then
            ax = m.linear_acceleration.x + (kick if n % 5 == 0 else 0.0)
            est.add_imu(t, ax, m.linear_acceleration.y, m.angular_velocity.z)
        else:
            est.add_joint_state(t, m.velocity[0], m.velocity[1])
    return est.drain_estimates()


def _assert_same_estimates(a: list[Any], b: list[Any]) -> None:
    assert len(a) == len(b) > 500
    for field in dataclasses.fields(a[0]):
        x = np.array([getattr(e, field.name) for e in a], dtype=float)
        y = np.array([getattr(e, field.name) for e in b], dtype=float)
        scale = float(np.max(np.abs(x))) if x.size else 0.0
        worst = float(np.max(np.abs(x - y))) if x.size else 0.0
        assert worst <= RTOL * scale, f"{field.name}: differs by {worst:.3g} (scale {scale:.3g})"


CONFIGS = {
    "default": SkidSteerEstimatorConfig(),
    "brush": SkidSteerEstimatorConfig(model="brush"),
    "scales_and_resistance": SkidSteerEstimatorConfig(
        tire_scales=TireScaleConfig(
            states=("friction", "cornering_stiffness", "motion_resistance"), reversion_time_s=20.0
        ),
        consider=ConsiderConfig(parameters=("longitudinal_stiffness",)),
    ),
    "adapt_r_no_consider": SkidSteerEstimatorConfig(
        noise_adaptation=InnovationNoiseConfig(adapt_r=True), consider=ConsiderConfig(parameters=())
    ),
}


#: The a_x push of every fifth IMU sample per configuration (m/s²). With the friction scale and the resistance
#: state the filter is chaotic under pushes: the Python step against itself with one ulp added to every a_x
#: differs by 1.3 m/s in v_x at a 2 m/s² push (and by 2e-13 m/s without): any two summation orders part
#: there, so that configuration runs unpushed.
KICKS = {"default": 2.0, "brush": 2.0, "adapt_r_no_consider": 2.0, "scales_and_resistance": 0.0}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_compiled_step_is_the_python_step_for_each_brush_configuration(name: str) -> None:
    """Other brush models, scale and resistance states, R adaptation, with strong tracking acting."""
    config = CONFIGS[name]
    kick = KICKS[name]
    fast, ref = SkidSteerEstimator(config), SkidSteerEstimator(config)
    assert fast.compiled_available and fast.use_compiled
    ref.use_compiled = False
    calls = {"n": 0}
    run = fast._compiled.run  # type: ignore[union-attr]

    def counted(*args: Any) -> Any:
        out = run(*args)
        calls["n"] += out[0] == STATUS_OK
        return out

    fast._compiled.run = counted  # type: ignore[union-attr, method-assign]
    a = _feed(fast, "skid_steer_small_radius_turn", kick=kick)
    b = _feed(ref, "skid_steer_small_radius_turn", kick=kick)
    _assert_same_estimates(a, b)
    assert calls["n"] >= len(a) - 2  # every step but the initialisation ran compiled
    assert any(e.fading_factor > 1.0 for e in a)  # the λ > 1 branch was exercised


def test_kinematic_models_and_other_variants_keep_the_python_step() -> None:
    for config in (
        SkidSteerEstimatorConfig(model="kinematic"),
        SkidSteerEstimatorConfig(filter="an_stukf"),
        SkidSteerEstimatorConfig.paper(),
    ):
        assert not SkidSteerEstimator(config).compiled_available


def test_a_covariance_the_python_step_must_project_is_handed_back() -> None:
    """An indefinite P (robust_sqrt's PSD projection) or too many sub-steps: STATUS_FALLBACK, nothing computed."""
    est = SkidSteerEstimator(SkidSteerEstimatorConfig())
    step = est._compiled
    assert step is not None
    n = step.mc.n
    x = np.array([2.0, 0.0, 0.1] + [0.0] * (n - 3))
    psi = np.zeros((len(step.s_idx), len(step.c_idx)))
    ok = step.run(x, np.eye(n) * 1e-3, None, np.zeros(3), 5.0, 5.0, 0.0, 0.0, 0.8, 0.01, psi)
    assert ok[0] == STATUS_OK
    indefinite = np.eye(n) * 1e-3
    indefinite[1, 1] = -1e-6
    assert step.run(x, indefinite, None, np.zeros(3), 5.0, 5.0, 0.0, 0.0, 0.8, 0.01, psi)[0] == STATUS_FALLBACK
    # at standstill a 10 s step needs far more than max_substeps Euler sub-steps
    assert step.run(x, np.eye(n) * 1e-3, None, np.zeros(3), 0.0, 0.0, 0.0, 0.0, 0.8, 10.0, psi)[0] == STATUS_FALLBACK
