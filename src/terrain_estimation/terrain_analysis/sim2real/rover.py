"""Replay model of a rocker-bogie (Kapvik) bag for the sim-to-real attribution (issue 6).

The full multibody plant (:mod:`vehicle_sim.plants.rover`) runs about 2.5×
real time; the attribution engine calls :meth:`RoverReplay.predict` a few
hundred times per bag. This replay is therefore *quasi-static and driven by
the bag's own measurements*: at 2 cm/s the inertial terms of the body and
bogie rows of the equations of motion are below the sensor noise (measured on
the simulator: ≤ 4e-3 N·m against 1e-2 N·m of load-cell noise in the
moments), so each 50 Hz sample is an algebraic problem. No path and no soil
state are integrated, and the terrain under the wheels is never needed: the
contact angles follow from the load cells and the soil model.

What the replay assumes
    * The rover parameters (masses, geometry, r_w, b_w, I_wg, b_d) of the
      config (``vehicle.*``) and the config's soil (``soil.*`` of the
      simulator section, [RB] Table II by default) with the plant's
      4th-order Wong–Reece surrogate (:mod:`vehicle_sim.terrain.terramechanics_surrogate`).
    * Two-axis load cells (``estimator.load_cell_axes: 2``): F_L and F_⊥ per
      wheel (single-axis cells leave W, DP and γ underdetermined per wheel;
      a :class:`~terrain_analysis.sim2real.where.Sim2RealError` says so).
    * All sensors on one clock; the effort is the torque applied from its
      stamp on (zero-order hold, as the plant's controller).

Relations used (one set per sample; symbols as MODELS.md C.3–C.6)
    Load cells → soil forces. Cell j reads, in its carrier frame at
    ε_j = θ + q1 (bogie wheels) or θ (front), F_⊥ along the carrier x axis and
    F_L along its z axis (eqs. 81–82). In the body frame the force on wheel j
    is F_j = R(ε_j − θ) (F_⊥, F_L), R(a) b = (b_x cos a + b_z sin a, −b_x sin a + b_z cos a).

    1. Whole-rover force balance (rows x0, z0 of eq. 32, quasi-static):
       m f = Σ_j F_j, with f the body specific force at O (eqs. 72–73) and
       m = m0 + m1 + 3 m_w. Predicts the **accelerometer** ``accel_x``,
       ``accel_z`` from the load cells (measured on the simulator to 6e-5 m/s²
       against 1.2e-3 m/s² of noise). Independent of soil and terrain.
    2. Moment balances (rows θ and q1 of eq. 32): with P_j the body-frame
       vector O → wheel centre j and B_j bogie joint → wheel centre j,
       Σ_j P_j × F_j − Σ_j τ_R,j − ∂V/∂θ = 0 and Σ_bogie B_j × F_j − τ_R,1 − τ_R,2
       − ∂V/∂q1 = 0, where the soil's resistive torques follow from the wheel
       rows, τ_R,j = τ_W,j − b_d q̇_j − I_wg q̈_j (q̇, q̈ by central differences
       of the encoder angles; τ_W the effort held over the sample before and
       after, so both sides average the same interval). The channels
       ``moment_body`` and ``moment_bogie`` are the load-cell side (N·m); the
       prediction is the effort side. Independent of soil and terrain.
    3. Soil (eqs. 1–2, 7–9 via the surrogate): per wheel, the unknowns W_j,
       i_j and δ_j = γ_j − ε_j follow from τ_R,j = τ_R(W_j, i_j),
       F_L² + F_⊥² = W_j² + DP(W_j, i_j)² and
       δ_j = atan2(F_⊥, F_L) − atan2(DP_j, W_j) (safeguarded Newton on i,
       vectorised, iterated to convergence: :func:`_solve_wheels`).
       The wheel centre then moves at v_j = r_w ω_j (1 − i_j) (eq. 1; eq. 2
       for skid) along the terrain tangent, at γ_j − θ = δ_j + (ε_j − θ)
       below the body x axis, with ω_j the absolute spin θ̇ (+ q̇1) + q̇_j.
       Rigid-body kinematics give each wheel's estimate of the body velocity
       at O: ẋ0^R = v_j cos(γ_j − θ) − θ̇ P_j,z − q̇1 B_j,z and
       ż0^R = −v_j sin(γ_j − θ) + θ̇ P_j,x + q̇1 B_j,x. The channel
       ``velocimeter`` is the mean of the three ẋ0^R; ``vz_front_middle``
       and ``vz_middle_rear`` are the differences of the wheels' ż0^R (0 for
       a rigid rover whose soil model is right: a wrong DP of ΔDP tilts a
       wheel's inferred velocity by ΔDP/W). These carry the soil effects.
    4. Pitch and gyro: the pitch is gravity's direction in the body frame,
       θ = atan2(−(f_x − a_x), f_z − a_z), where the body acceleration
       (a_x, a_z) is the derivative (0.1 s Savitzky–Golay) of the wheels'
       mean estimate of (ẋ0^R, ż0^R) of relation 3 (it reaches 1e-2 m/s² when
       a wheel enters another soil: 1e-3 rad of false pitch otherwise).
       θ and θ̇ are quadratic Savitzky–Golay fits over 3 s (the accelerometer's
       noise, 1.3e-4 rad of pitch per sample, would otherwise dominate θ̇);
       the bogie rate q̇1 over 1 s of encoder angles. ``pitch_rate``
       predicts the gyro as θ̇ (its noise, 0.56 °/s, is far above the pitch
       rates at 2 cm/s: the channel carries the gyro bias).

    Samples within 3 s of the start (the smoothing windows) are left out
    (``warmup``).

Effects (:data:`vehicle_sim.effects.CATALOGUE` ``["rover"]``), as the plant implements them
    * ``load_cell_bias``, ``load_cell_crosstalk``: the plant reads
      F_L + c F_⊥ + b and F_⊥ + c F_L; the replay inverts this on the
      measured cells before every relation, and predicts the load-cell side
      of the moment channels as the cells would read it.
    * ``imu_bias``: accelerometer (x, z) and gyro biases added to the
      predictions; the pitch is taken from the bias-corrected accelerometer.
    * ``sensor_delay``: every channel but the effort lags by d; the replay
      shifts the effort by d (linear interpolation) so that it meets the
      delayed state.
    * ``slip_sinkage``: the surrogate at W (1 + c|i|), forces divided by 1 + c|i|
      (the plant's force-level form, exact).
    * ``grousers``: the plant evaluates a surrogate fitted for radius r_w + h_g
      at the tip slip 1 − (1 − i) r_w/(r_w + h_g); the replay uses the nominal
      surrogate at the tip slip plus the Wong–Reece difference
      WR(r_w + h_g) − WR(r_w) fitted as the plant fits its surrogate, on a
      30 × 30 instead of a 100 × 100 grid (the approximation).
    * ``soil_change``: the same difference for the changed soil, blended in
      over 2 mm of wheel-centre travel beyond ``soil_change_distance``
      (the plant switches at x_j ≥ d; the blend keeps the fit of d smooth). Wheel-centre x is O's x, integrated from
      the velocimeter from 0 at the bag's start (the plant's start_x = 0),
      plus the wheel's offset. The distance candidate starts where a
      linearised change-point scan of the nominal residual puts the change,
      refined with the replay's own cost near its best local minimum
      (:meth:`RoverReplay._change_location`; its "off" is immaterial while the
      soil scales are 1). With the 30 × 30 difference replaced by the plant's
      own 100 × 100 surrogate of the changed soil, the held-out residual of
      the withheld-effect suite's soil-change bags with their true parameters
      is the same within 1.5 %: the grid is not what limits this effect.
    * ``vertical_velocity`` (path undulation): **not a candidate.** The replay
      takes the configuration from the sensors and infers the contact angles,
      so the terrain's shape, undulation included, is part of its input: an
      undulation of the wheel-centre path is not distinguishable from terrain
      (the Fig. 10 rolling terrain itself has a 0.9 m, 12 mm component). A
      note says so in every model.

Noise budgets
    Each channel's σ is what the config's sensor noise (``noise.*``) does to
    its residual through the replay: four Monte Carlo realisations of that
    noise are added to the measured inputs and replayed with the nominal
    model; the spread of the change of the residual is the propagated noise.
    The smoothing colours it (the ż0^R differences most), so σ is the level
    of the white noise that bounds its PSD in every octave band from 0.5 Hz
    (:func:`_white_bound`), not only its variance, as the attribution's noise
    tests assume white residuals. A model-error floor (:data:`MODEL_FLOORS`,
    below the noise) is added in quadrature.

Measured (simulator, Table IV noise; ``test/test_sim2real_rover.py``)
    Nominal runs on terrains rolling, uphill and step_sharp: every channel's
    residual RMS 0.5–1.0 σ. With an effect on, the replay with that effect at
    the plant's value brings every channel back to ≤ 1.3 σ for load-cell
    bias and cross-talk, IMU biases, slip-sinkage and grousers. Soil change:
    the same away from the change; for ≈ 1 s after a wheel crosses it the
    plant's transient (body acceleration spike, bogie rate step) is faster
    than the smoothing above and leaves a residual of a few σ in the ż0^R
    differences (still far below the nominal replay's there). At the one
    sample where a wheel enters the changed soil, the central differences of
    the encoder angles straddle the switch of τ_R: a few σ in the moment and
    accelerometer channels, ≈ 13 σ in ``vz_front_middle`` (test's run, front
    wheel, true parameters). Until session 7 the plant's load cells reported
    the normal load held from the previous step (computed with the old soil's
    forces) instead of the reaction that acts, 0.5–3 N apart at that sample:
    44 σ in ``moment_body`` there, a simulator artefact the plant no longer
    has.

Outside the domain: a rover sliding backward
    A rover that cannot climb stalls and slides back under turning wheels
    (slip beyond 1, body accelerations of 0.5 m/s²): outside the soil model's
    slip range and the quasi-static balance. Such stretches, widened by 1.5 s
    either side, are left out of every fit, score and test (``valid``,
    :meth:`RoverReplay._inside_domain`), with a note. Measured on the three
    withheld bags that slide (≈ 1.7 s each, velocimeter down to −0.06 to
    −0.34 m/s): 9a51da3d1271 (soil change; it kept 92 % of its gap with the
    true parameters before) and 62b94e4b601a (slip-sinkage c = 1.47) are now
    attributed right; b5507c8f9e04 (c = 1.30) still is not: with the true c
    the ż0^R differences leave 35–8600 σ² per second over the 3 s before the
    slide, while the inferred slips rise from 0.45 to 0.55 (the approach to
    the stall is already outside what the replay reproduces; not understood).

What the bag shows only to a likelihood ratio, and what it cannot show
    * ``sensor_delay``: only the effort is undelayed, and at 2 cm/s it changes
      by ≈ 2e-4 N·m per sample; a 60 ms delay moves τ_R by ≈ 1e-3 N·m, the
      slip by ≈ 3e-4: the replay with and without the delay differ by less
      than 0.05 in mean r² on every channel, far below what the noise tests
      flag, and its held-out χ² drop (≈ 0.3 %) is below the engine's
      relative-improvement guard. It is coherent, though: on a 30 s bag the
      χ² over all samples falls by ≈ 40 (noise-budget units) from 0 to the
      best delay. The engine's cross-fitted held-out likelihood-ratio test
      (:func:`terrain_analysis.sim2real.attribution._cross_fitted`, issue 22
      item 4) finds it. Measured on 30 s rolling-terrain bags (plant without
      the sinkage transient, ``wheel_sinkage=False``): 60 ms fitted as 39,
      44 and 62 ms (the χ² minimum over all samples of the first is at
      ≈ 40 ms: the moment channels favour it, ``vz_front_middle`` no delay —
      not understood), 100 ms as 99 ms.
    * ``vertical_velocity``: see above (not a candidate). Listed as "not
      identifiable from this bag" (attribute ``unidentifiable``) with the
      measurement that would identify it.

Units: SI (m, s, kg, rad, N, N·m).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from terrain_analysis.sim2real.model import (
    Candidate,
    Channel,
    FitParameter,
    ReplayModel,
    StampOrigin,
    candidates_from_catalogue,
)
from terrain_analysis.sim2real.where import Sim2RealError
from terrain_estimation.bag import bag_topics
from terrain_estimation.models.rover import RoverParams

__all__ = [
    "MODEL_FLOORS",
    "RoverReplay",
    "RoverSeries",
    "build_model",
    "build_model_from_series",
    "read_rover_bag",
    "series_from_run",
]

FloatArray = NDArray[np.float64]
Progress = Callable[[str], None] | None

_WHEELS = ("rear", "middle", "front")
_LOCAL_ORDER = 4
_FIT_GRID_POINTS = 30  # per axis, of the surrogate fit of a changed soil or grouser wheel
_BLEND_WIDTH = 2.0e-3  # m, soil-change blend
_LOCATION_SCALE = 0.02  # m, scale of the soil-change distance started at the change-location scan
_LOCATION_WINDOW = 0.15  # m, either side of the linearised scan's location, of the replay's scan of it
_LOCATION_NFEV = 20  # evaluations of each fit of the soil scales in the location refinement
_LOCATION_ROUNDS = 3  # at most, of the location refinement (fit the scales, scan the location)
#: Effects that change the inputs or the soil model of the per-wheel inversion (the others reuse the nominal one).
_SOIL_INPUT_EFFECTS = frozenset(
    {"load_cell_bias", "load_cell_crosstalk", "sensor_delay", "slip_sinkage", "grousers", "soil_change"}
)
_SMOOTH_WINDOW = 3.0  # s, Savitzky-Golay window of the accelerometer pitch
_BOGIE_WINDOW = 1.0  # s, Savitzky-Golay window of the bogie rate
_ACCEL_WINDOW = 0.1  # s, Savitzky-Golay window of the body acceleration from the wheels' velocities

#: Model-error floors σ_model per channel (added in quadrature to the propagated noise): the nominal replay's
#: largest residual RMS on noiseless 15 s simulator runs (terrains rolling and step_sharp), rounded up.
MODEL_FLOORS: Mapping[str, float] = {
    "accel_x": 1.5e-5,
    "accel_z": 1.5e-5,
    "pitch_rate": 3.0e-5,
    "moment_body": 5.0e-4,
    "moment_bogie": 3.0e-4,
    "velocimeter": 8.0e-6,
    "vz_front_middle": 8.0e-6,
    "vz_middle_rear": 8.0e-6,
}


# ---------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class RoverSeries:
    """The contract's rover sensor streams on one time grid (N samples).

    Attributes:
        t: sample times (s from the first sample), increasing.
        accel: body specific force (x, z) (m/s²), (N, 2).
        gyro: pitch rate (rad/s), (N,).
        bogie: bogie angle q1 (rad), (N,).
        wheel_angle: q2..q4 (rear, middle, front) (rad), (N, 3).
        effort: applied wheel torques (N·m), (N, 3).
        speed: velocimeter forward speed (m/s), (N,).
        load_axial: F_L per wheel (N), (N, 3).
        load_perpendicular: F_⊥ per wheel (N), (N, 3).
    """

    t: FloatArray
    accel: FloatArray
    gyro: FloatArray
    bogie: FloatArray
    wheel_angle: FloatArray
    effort: FloatArray
    speed: FloatArray
    load_axial: FloatArray
    load_perpendicular: FloatArray


def series_from_run(run: Any) -> RoverSeries:
    """The sensor streams of a :class:`vehicle_sim.plants.rover.RoverRun` (tests; no bag needed)."""
    s = run.sensors
    return RoverSeries(
        t=np.asarray(run.time, dtype=float) - float(run.time[0]),
        accel=np.asarray(s.acceleration, dtype=float),
        gyro=np.asarray(s.pitch_rate, dtype=float),
        bogie=np.asarray(s.bogie_angle, dtype=float),
        wheel_angle=np.asarray(s.wheel_angle, dtype=float),
        effort=np.asarray(s.effort, dtype=float),
        speed=np.asarray(s.forward_velocity, dtype=float),
        load_axial=np.asarray(s.load_axial, dtype=float),
        load_perpendicular=np.asarray(s.load_perpendicular, dtype=float),
    )


def read_rover_bag(
    bag: str | Path,
    *,
    namespace: str = "/rover",
    joints: Mapping[str, str] | None = None,
) -> RoverSeries:
    """Read the contract's rover topics of ``bag`` onto the joint_states time grid.

    Other streams are linearly interpolated to the joint_states stamps (on a
    simulator bag all stamps coincide). ``ground_truth/*`` is never read.

    Raises:
        Sim2RealError: a topic is missing or too short, a joint is missing, a
            value is not finite (the message names topic, field and value).
    """
    from terrain_estimation.bag import read_bag
    from terrain_estimation.tools.estimate import topic_name

    names = dict(joints or {"bogie": "bogie", "rear": "rear_wheel", "middle": "middle_wheel", "front": "front_wheel"})
    topics = {
        "imu": topic_name(namespace, "imu"),
        "joint_states": topic_name(namespace, "joint_states"),
        "velocimeter": topic_name(namespace, "velocimeter"),
        **{f"load_{w}": topic_name(namespace, f"wheel/{w}/load") for w in _WHEELS},
    }
    by_topic = {v: k for k, v in topics.items()}
    present = bag_topics(bag)
    missing = [t for t in topics.values() if t not in present]
    if missing:
        raise Sim2RealError(
            f"bag {str(bag)!r} has no messages on {', '.join(missing)}, which the rover replay needs "
            f"(namespace {namespace!r}; pass --namespace if the bag was recorded under another one; "
            f"the bag has {', '.join(sorted(present)) or 'no topics'})"
        )
    rows: dict[str, list[tuple[float, ...]]] = {k: [] for k in topics}
    order = [names["bogie"], names["rear"], names["middle"], names["front"]]
    clock = StampOrigin()  # seconds from the first stamp (epoch stamps lose precision as floats)
    for item in read_bag(bag, list(by_topic)):
        key = by_topic[item.topic]
        msg = item.msg
        t = clock(msg)
        if key == "imu":
            a, w = msg.linear_acceleration, msg.angular_velocity
            rows[key].append((t, float(a.x), float(a.z), float(w.y)))
        elif key == "joint_states":
            joint_names = list(msg.name)
            missing_joints = [n for n in order if n not in joint_names]
            if missing_joints:
                raise Sim2RealError(
                    f"{item.topic}: joint(s) {missing_joints} missing (message has {joint_names}); "
                    "set joints.* in the config"
                )
            idx = [joint_names.index(n) for n in order]
            if len(msg.position) < len(joint_names):
                raise Sim2RealError(
                    f"{item.topic}: position has {len(msg.position)} values for {len(joint_names)} joints"
                )
            effort = list(msg.effort) if len(msg.effort) >= len(joint_names) else None
            if effort is None:
                raise Sim2RealError(
                    f"{item.topic}: field effort has {len(msg.effort)} values for {len(joint_names)} joints; "
                    "the rover replay needs the applied wheel torques"
                )
            rows[key].append((t, *(float(msg.position[i]) for i in idx), *(float(effort[i]) for i in idx[1:])))
        elif key == "velocimeter":
            rows[key].append((t, float(msg.twist.linear.x)))
        else:
            f = msg.wrench.force
            rows[key].append((t, float(f.z), float(f.x)))
    fields = {
        "imu": ("linear_acceleration.x", "linear_acceleration.z", "angular_velocity.y"),
        "joint_states": (
            "position[bogie]",
            "position[rear]",
            "position[middle]",
            "position[front]",
            "effort[rear]",
            "effort[middle]",
            "effort[front]",
        ),
        "velocimeter": ("twist.linear.x",),
        **{f"load_{w}": ("wrench.force.z", "wrench.force.x") for w in _WHEELS},
    }
    arrays: dict[str, FloatArray] = {}
    for key, topic in topics.items():
        if len(rows[key]) < 10:
            raise Sim2RealError(
                f"bag {str(bag)!r} has {len(rows[key])} messages on {topic}; the rover replay needs it "
                f"(namespace {namespace!r}; pass --namespace if the bag was recorded under another one)"
            )
        a = np.array(rows[key], dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        bad = ~np.isfinite(a)
        if np.any(bad):
            r, c = np.argwhere(bad)[0]
            what = "header.stamp" if c == 0 else fields[key][c - 1]
            raise Sim2RealError(f"{topic}: field {what} is {float(a[r, c])} at message {r} (stamp {a[r, 0]:.9f} s)")
        keep = np.concatenate([[True], np.diff(a[:, 0]) > 0.0])
        arrays[key] = a[keep]
    grid = arrays["joint_states"][:, 0]
    t0 = float(grid[0])

    def on_grid(key: str, column: int) -> FloatArray:
        a = arrays[key]
        return np.interp(grid, a[:, 0], a[:, column])

    js = arrays["joint_states"]
    return RoverSeries(
        t=grid - t0,
        accel=np.column_stack([on_grid("imu", 1), on_grid("imu", 2)]),
        gyro=on_grid("imu", 3),
        bogie=js[:, 1].copy(),
        wheel_angle=js[:, 2:5].copy(),
        effort=js[:, 5:8].copy(),
        speed=on_grid("velocimeter", 1),
        load_axial=np.column_stack([on_grid(f"load_{w}", 1) for w in _WHEELS]),
        load_perpendicular=np.column_stack([on_grid(f"load_{w}", 2) for w in _WHEELS]),
    )


# ---------------------------------------------------------------------------
# Soil
# ---------------------------------------------------------------------------


class _Polynomial:
    """Σ c[k, m] |i|^k W^m (k + m ≤ 4) in slip magnitude |i| (–) and load W (N), evaluated by Horner's scheme."""

    def __init__(self, table: FloatArray) -> None:
        self.table = np.asarray(table, dtype=float)
        self.order = self.table.shape[0] - 1

    @classmethod
    def from_model(cls, model: Any) -> _Polynomial:
        """From a :class:`~terrain_estimation.models.terrain_response.PolynomialModel2D` (the plant's surrogate)."""
        table = np.zeros((model.order + 1, model.order + 1))
        for (k, m), c in zip(model.exponents, model.coefficients, strict=True):
            table[k, m] = c
        return cls(table)

    def __add__(self, other: _Polynomial) -> _Polynomial:
        return _Polynomial(self.table + other.table)

    def __call__(self, slip: FloatArray | float, load: FloatArray) -> FloatArray:
        result = np.zeros(np.shape(load))
        for k in range(self.order, -1, -1):
            q = np.zeros(np.shape(load))
            for m in range(self.order - k, -1, -1):
                q = q * load + self.table[k, m]
            result = result * slip + q
        return result


def _powers(x: FloatArray, order: int) -> FloatArray:
    """(n, order + 1) matrix of x⁰ … x^order."""
    out = np.empty((x.size, order + 1))
    out[:, 0] = 1.0
    for k in range(1, order + 1):
        out[:, k] = out[:, k - 1] * x
    return out


class _SurrogateFit:
    """The plant's surrogate fit (4th order, equal weights, basis |i|^k W^m over 0 ≤ i ≤ 1, 0.1 ≤ W ≤ 200 N) on a
    coarser grid (30 × 30 instead of 100 × 100), so that a changed soil costs one 900-point Wong–Reece solve."""

    def __init__(self, order: int = _LOCAL_ORDER, points: int = _FIT_GRID_POINTS) -> None:
        from vehicle_sim.terrain.terramechanics_surrogate import SURROGATE_LOAD_RANGE, SURROGATE_SLIP_RANGE

        self.order = order
        self.exponents = [(k, m) for k in range(order + 1) for m in range(order + 1 - k)]
        load = np.linspace(*SURROGATE_LOAD_RANGE, points)
        slip = np.linspace(*SURROGATE_SLIP_RANGE, points)
        lm, sm = np.meshgrid(load, slip, indexing="ij")
        self.grid_load, self.grid_slip = lm.ravel(), sm.ravel()
        self._load_scale = float(SURROGATE_LOAD_RANGE[1])
        features = np.stack(
            [self.grid_slip**k * (self.grid_load / self._load_scale) ** m for k, m in self.exponents], axis=1
        )
        self._pinv = np.linalg.pinv(features)

    def fit(self, values: FloatArray) -> _Polynomial:
        c = self._pinv @ values
        table = np.zeros((self.order + 1, self.order + 1))
        for (k, m), value in zip(self.exponents, c, strict=True):
            table[k, m] = value / self._load_scale**m
        return _Polynomial(table)


@dataclass(frozen=True)
class _SoilVariant:
    """A soil and grouser height whose forces differ from the nominal surrogate."""

    soil: Any
    grouser_height: float


class _SoilModel:
    """DP(W, i), τ_R(W, i) as the plant evaluates them (``_Terramechanics``), with the catalogue's soil effects.

    Nominal: the plant's surrogate of the config soil (the same polynomials).
    A variant (changed soil and/or grousers) is the surrogate plus the fit,
    by the plant's own procedure on a 30 × 30 grid, of the Wong–Reece
    difference WR(variant) − WR(nominal): the plant fits a new surrogate to
    WR(variant) on 100 × 100 points, and the fit of a sum is the sum of the
    fits, so only the grid differs (and the surrogate's fit error, 0.1–0.3 N
    of DP near the operating point, is reproduced rather than ignored).
    """

    def __init__(self, soil: Any, params: RoverParams) -> None:
        from vehicle_sim.terrain.terramechanics_surrogate import SURROGATE_LOAD_RANGE, terramechanics_surrogate
        from vehicle_sim.terrain.wong_reece import RigidWheel

        self.soil = soil
        self.params = params
        self.wheel = RigidWheel(radius=params.wheel_radius, width=params.wheel_width)
        surrogate = terramechanics_surrogate(soil, self.wheel)
        self.nominal = (
            _Polynomial.from_model(surrogate.drawbar_pull),
            _Polynomial.from_model(surrogate.resistive_torque),
        )
        self.load_cap = SURROGATE_LOAD_RANGE[1]
        self.local = _SurrogateFit()
        self._base = self._wong_reece(soil, self.wheel)
        self._cache: dict[tuple[Any, float], tuple[_Polynomial, _Polynomial]] = {}

    def _wong_reece(self, soil: Any, wheel: Any) -> tuple[FloatArray, FloatArray]:
        from vehicle_sim.terrain.wong_reece import wheel_forces

        forces = wheel_forces(self.local.grid_load, self.local.grid_slip, soil, wheel, overload="saturate")
        return np.asarray(forces.drawbar_pull, dtype=float), np.asarray(forces.resistive_torque, dtype=float)

    def polynomials(self, variant: _SoilVariant | None) -> tuple[_Polynomial, _Polynomial]:
        """(DP, τ_R) polynomials in (|i|, W) of the nominal soil (None) or a variant."""
        from vehicle_sim.terrain.wong_reece import RigidWheel

        if variant is None or (variant.soil == self.soil and variant.grouser_height == 0.0):
            return self.nominal
        key = (variant.soil, round(variant.grouser_height, 12))
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            wheel = RigidWheel(radius=self.params.wheel_radius + variant.grouser_height, width=self.params.wheel_width)
            dp, tau = self._wong_reece(variant.soil, wheel)
            self._cache[key] = (
                self.nominal[0] + self.local.fit(dp - self._base[0]),
                self.nominal[1] + self.local.fit(tau - self._base[1]),
            )
        return self._cache[key]

    def forces(
        self,
        load: FloatArray,
        slip: FloatArray,
        *,
        sinkage: float = 0.0,
        grouser_height: float = 0.0,
        variants: Sequence[tuple[_SoilVariant | None, FloatArray | float]] = ((None, 1.0),),
    ) -> tuple[FloatArray, FloatArray]:
        """(DP, τ_R) at (W, i) in the plant's ``_Terramechanics`` order of effects.

        ``variants``: (variant or None for the nominal soil, weight per sample)
        blended (the soil before and after a change).
        """
        load = np.maximum(load, 0.0)
        slip = np.clip(slip, -1.0, 1.0)
        model_load, model_slip = load, slip
        scale = None
        if sinkage > 0.0:
            scale = 1.0 + sinkage * np.abs(slip)
            model_load = load * scale
        if grouser_height > 0.0:
            r = self.params.wheel_radius
            model_slip = 1.0 - (1.0 - slip) * r / (r + grouser_height)
        capped = np.minimum(model_load, self.load_cap)
        skid = model_slip < 0.0
        any_skid = bool(np.any(skid))
        load_powers = _powers(capped, _LOCAL_ORDER)
        slip_powers = _powers(np.abs(model_slip), _LOCAL_ORDER)
        dp = np.zeros_like(capped)
        tau = np.zeros_like(capped)
        for variant, weight in variants:
            p_dp, p_tau = self.polynomials(variant)
            both = slip_powers @ np.hstack([p_dp.table, p_tau.table])  # Σ_k |i|^k c_km, for DP and τ_R
            v_dp = np.einsum("nm,nm->n", both[:, : _LOCAL_ORDER + 1], load_powers)
            v_tau = np.einsum("nm,nm->n", both[:, _LOCAL_ORDER + 1 :], load_powers)
            if any_skid:  # [RB] eqs. 10-11 on the polynomials, as the plant's surrogate
                v_dp = np.where(skid, -v_dp + 2.0 * (load_powers @ p_dp.table[0]), v_dp)
                v_tau = np.where(skid, -v_tau + 2.0 * (load_powers @ p_tau.table[0]), v_tau)
            dp = dp + weight * v_dp
            tau = tau + weight * v_tau
        if scale is not None:
            dp = dp / scale
            tau = tau / scale
        return dp, tau


# ---------------------------------------------------------------------------
# Replay
# ---------------------------------------------------------------------------


@functools.lru_cache(maxsize=32)
def _savgol_operator(window: int, deriv: int, dt: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Quadratic Savitzky–Golay filter as (interior kernel, first-window map, last-window map).

    The edges are the quadratic fitted to the first / last ``window`` samples
    (scipy's ``mode="interp"``), as fixed linear maps so that every call is a
    convolution and two small products.
    """
    half = window // 2
    kernel = np.asarray(signal.savgol_coeffs(window, 2, deriv=deriv, delta=dt, use="conv"), dtype=float)
    x = np.arange(window, dtype=float)
    fit = np.linalg.pinv(np.vander(x, 3, increasing=True))  # (3, window): coefficients of 1, x, x²
    pos = np.arange(window, dtype=float)
    if deriv == 0:
        basis = np.vander(pos, 3, increasing=True)
    elif deriv == 1:
        basis = np.column_stack([np.zeros(window), np.ones(window), 2.0 * pos]) / dt
    else:
        basis = np.column_stack([np.zeros(window), np.zeros(window), 2.0 * np.ones(window)]) / dt**2
    full = basis @ fit  # (window, window): value at each position of the window
    return kernel, full[:half], full[window - half :]


def _savgol(x: FloatArray, window: int, deriv: int, dt: float) -> FloatArray:
    """Quadratic Savitzky–Golay smoothing / derivative along axis 0 (edges as scipy's ``mode="interp"``)."""
    window = max(5, window | 1)
    n = x.shape[0]
    if n <= window:
        window = (n - 1) | 1 if n % 2 == 0 else n - 2
        if window < 5:
            return np.gradient(x, dt, axis=0) if deriv else x.copy()
    kernel, first, last = _savgol_operator(window, deriv, round(dt, 12))
    half = window // 2
    if x.ndim == 1:
        out = np.empty(n)
        out[half : n - half] = np.convolve(x, kernel, mode="valid")
    else:
        out = np.empty(x.shape)
        for j in range(x.shape[1]):
            out[half : n - half, j] = np.convolve(x[:, j], kernel, mode="valid")
    out[:half] = first @ x[:window]
    out[n - half :] = last @ x[n - window :]
    return out


def _white_bound(samples: Sequence[FloatArray], rate: float) -> float:
    """σ of the white noise whose PSD bounds that of ``samples`` in every octave band above 0.5 Hz (and its variance).

    Welch PSD (Hann, 50 % overlap, ≈ 4 s segments as the noise tests use),
    mean over each octave band from 0.5 Hz to Nyquist; a white noise of
    variance σ² has the one-sided PSD 2σ²/rate.
    """
    variance = float(np.mean([np.var(x) for x in samples]))
    n = min(x.size for x in samples)
    nperseg = int(min(2 ** int(round(math.log2(max(rate * 4.0, 16.0)))), 2 ** int(math.log2(max(n // 8, 16)))))
    if n < 2 * nperseg:
        return math.sqrt(variance)
    spectra = [signal.welch(x, fs=rate, nperseg=nperseg, detrend="constant") for x in samples]
    f = spectra[0][0]
    psd = np.mean([p for _, p in spectra], axis=0)  # averaged over the realisations
    bound = variance
    low = 0.5
    while low < rate / 2.0:
        band = (f >= low) & (f < 2.0 * low)
        if np.any(band):
            bound = max(bound, float(np.mean(psd[band])) * rate / 2.0)
        low *= 2.0
    return math.sqrt(bound)


def _rotate(angle: FloatArray | float, bx: FloatArray, bz: FloatArray) -> tuple[FloatArray, FloatArray]:
    c, s = np.cos(angle), np.sin(angle)
    return bx * c + bz * s, -bx * s + bz * c


_SLIP_BOUNDS = (-0.95, 0.999)  # slip range of the per-wheel inversion
_TORQUE_TOL = 1e-6  # N·m, convergence of τ_R(W, i) = τ_R,measured
_LOAD_TOL = 1e-4  # N, convergence of W = √(F_L² + F_⊥² − DP²)


def _solve_wheels(
    forces: Callable[[NDArray[np.intp] | None, FloatArray, FloatArray], tuple[FloatArray, FloatArray]],
    tau: FloatArray,
    force2: FloatArray,
    slip: FloatArray,
    load: FloatArray,
    sweeps: Sequence[tuple[int, int]],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(W, i, DP) per sample: τ_R(W, i) = ``tau`` and W² + DP(W, i)² = ``force2`` (module docstring, 3).

    ``forces(rows, W, i)`` is (DP, τ_R) at the samples ``rows`` (None: all).
    Each sweep is a safeguarded Newton on i at fixed W followed by the update
    of W. The Newton keeps, per sample, a slip where τ_R is below the
    measurement and one where it is above (at first the slip bounds) and
    bisects whenever the step leaves that bracket or the slope is not
    positive: a changed soil's τ_R(i) is nearly flat beyond i ≈ 0.3 (loose
    soil with a high friction angle: 1.79 N·m at i = 0.3, 1.84 N·m at 0.8), where
    a plain Newton step overshoots to the slip bounds and oscillates between
    them. After the ``sweeps`` (Newton iterations, ignored), samples whose
    torque or load has not converged get more iterations and sweeps.
    """
    lo, hi = _SLIP_BOUNDS
    step = 1e-4

    def newton(
        sel: NDArray[np.intp] | None,
        i: FloatArray,
        w: FloatArray,
        target: FloatArray,
        iterations: int,
        below: FloatArray,
        above: FloatArray,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        for _ in range(iterations):
            t0 = forces(sel, w, i)[1]
            t1 = forces(sel, w, np.minimum(i + step, 1.0))[1]
            f = t0 - target
            below = np.where(f < 0.0, i, below)
            above = np.where(f > 0.0, i, above)
            slope = (t1 - t0) / step
            good = slope > 1e-3
            trial = np.clip(i - f / np.where(good, slope, 1.0), lo, hi)
            inside = good & (trial >= np.minimum(below, above)) & (trial <= np.maximum(below, above))
            i = np.where(f == 0.0, i, np.where(inside, trial, 0.5 * (below + above)))
        return i, below, above

    def converged(f: FloatArray, i: FloatArray, below: FloatArray, above: FloatArray) -> NDArray[np.bool_]:
        # The torque matches, or the bracket has closed (at a slip bound when τ_R never reaches the measurement).
        result: NDArray[np.bool_] = (np.abs(f) <= _TORQUE_TOL) | (np.abs(above - below) <= 1e-9)
        return result

    def sweep(
        sel: NDArray[np.intp] | None, i: FloatArray, w: FloatArray, iterations: int
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """One sweep on the samples ``sel``: (i, DP at the old W, new W)."""
        target = tau if sel is None else tau[sel]
        f2 = force2 if sel is None else force2[sel]
        below, above = np.full(i.size, lo), np.full(i.size, hi)
        i, below, above = newton(sel, i, w, target, iterations, below, above)
        d, t = forces(sel, w, i)
        for attempt in range(10):  # the samples the fixed iterations left unconverged
            f = t - target
            below, above = np.where(f < 0.0, i, below), np.where(f > 0.0, i, above)
            bad = np.flatnonzero(~converged(f, i, below, above))
            if not bad.size:
                break
            sub = bad if sel is None else sel[bad]
            if attempt == 0:
                # The bracket's ends may still be the slip bounds, assumed rather than evaluated: evaluate them.
                # τ_R at the lower bound above the measurement (or at the upper one below it): the bound solves.
                f_lo = forces(sub, w[bad], np.full(bad.size, lo))[1] - target[bad]
                f_hi = forces(sub, w[bad], np.full(bad.size, hi))[1] - target[bad]
                at_lo, at_hi = f_lo >= 0.0, (f_hi <= 0.0) & (f_lo < 0.0)
                below[bad] = np.where(at_lo, lo, np.where(at_hi, hi, below[bad]))
                above[bad] = np.where(at_lo, lo, np.where(at_hi, hi, above[bad]))
                i[bad] = np.where(at_lo, lo, np.where(at_hi, hi, i[bad]))
            i[bad], below[bad], above[bad] = newton(sub, i[bad], w[bad], target[bad], 4, below[bad], above[bad])
            d[bad], t[bad] = forces(sub, w[bad], i[bad])
        return i, d, np.sqrt(np.maximum(f2 - d**2, 1e-6))

    if not tau.size:
        return slip, load, np.zeros(0)
    previous = load
    for iterations, _ in sweeps:
        slip, _, updated = sweep(None, slip, load, iterations)
        previous, load = load, updated
    # Samples whose W still moved in the last sweep get up to three more (a heavily skidding wheel's W may not settle).
    for _ in range(3):
        moving = np.flatnonzero(np.abs(load - previous) > _LOAD_TOL)
        if not moving.size:
            break
        slip[moving], _, updated = sweep(moving, slip[moving], load[moving], 2)
        previous[moving], load[moving] = load[moving], updated
    dp = forces(None, load, slip)[0]
    return slip, load, dp


class RoverReplay:
    """:class:`~terrain_analysis.sim2real.model.ReplayModel` of one rover bag (module docstring)."""

    vehicle = "rover"

    def __init__(
        self,
        series: RoverSeries,
        params: RoverParams,
        soil: Any,
        *,
        warmup: float = 3.0,
        noise: Mapping[str, float] | None = None,
        source: str = "",
        monte_carlo: int = 4,
        seed: int = 0,
    ) -> None:
        n = series.t.size
        if n < 50:
            raise Sim2RealError(f"{source or 'bag'}: {n} samples; the rover replay needs at least 50 (1 s at 50 Hz)")
        self.series = series
        self.params = params
        self.warmup = float(warmup)
        self.notes: list[str] = []
        dt = float(np.median(np.diff(series.t)))
        if not dt > 0.0:
            raise Sim2RealError(f"{source or 'bag'}: joint_states stamps do not increase (median step {dt} s)")
        self.dt = dt
        self.noise = dict(noise or {})
        self._t = series.t
        self._prepare()
        self._inside = self._inside_domain(self.noise.get("forward_speed", 0.0), source)
        self._warm_series: RoverSeries | None = None
        self._warm_start: tuple[FloatArray, FloatArray] | None = None
        self._nominal_state: tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None = None
        self.soil_model = _SoilModel(soil, params)
        self.soil = soil
        self._soil_weights: FloatArray | None = None
        self._build_channels(monte_carlo, seed)
        catalogue = candidates_from_catalogue("rover", exclude=("vertical_velocity",))
        self.candidates = self._adapt_candidates(catalogue)
        self.nuisance: list[FitParameter] = []
        #: Effects this replay cannot identify from any bag, with the measurement that would (issue 22, item 4).
        self.unidentifiable: dict[str, str] = {
            "vertical_velocity": "a measurement of the terrain under the wheels (a surveyed or lidar profile of the "
            "path): the replay infers the contact geometry from the load cells and the joint angles, so a path "
            "undulation is terrain to it"
        }
        self.notes.append(
            "vertical_velocity (path undulation) is not a candidate: the replay is driven by the measured "
            "configuration and infers the contact angles from the load cells, so the terrain's shape (an "
            "undulation included) is part of its input and cannot be told apart from terrain"
        )

    # --- preparation --------------------------------------------------------

    def _prepare(self) -> None:
        s, dt = self.series, self.dt
        q = s.wheel_angle
        rate = np.empty_like(q)
        rate[1:-1] = (q[2:] - q[:-2]) / (2.0 * dt)
        rate[0], rate[-1] = (q[1] - q[0]) / dt, (q[-1] - q[-2]) / dt
        accel = np.zeros_like(q)
        accel[1:-1] = (q[2:] - 2.0 * q[1:-1] + q[:-2]) / dt**2
        self._wheel_rate = rate
        self._wheel_accel = accel
        window = int(round(_SMOOTH_WINDOW / dt))
        self._window = window
        self._accel_window = int(round(_ACCEL_WINDOW / dt))
        self._accel_smooth = _savgol(s.accel, window, 0, dt)
        self._bogie_rate = _savgol(s.bogie, int(round(_BOGIE_WINDOW / dt)), 1, dt)
        self._speed_smooth = _savgol(s.speed, window, 0, dt)
        # Effort held over the sample before and after t_k (central differences average that interval).
        e = s.effort
        self._effort_mid = np.vstack([e[:1], 0.5 * (e[1:] + e[:-1])])
        p = self.params
        self._front = np.array(p.front_wheel_offset)
        self._joint = np.array(p.bogie_joint_offset)
        self._bogie_wheels = np.array(p.bogie_wheel_offsets)

    def _inside_domain(self, speed_noise: float, source: str) -> NDArray[np.bool_]:
        """Samples inside the quasi-static replay's domain: not while the rover slides backward.

        A rover that cannot climb (its wheels dig in, the drawbar pull falls below the grade
        resistance) stalls and slides back under turning wheels: slip beyond 1, body
        accelerations of 0.5 m/s² and more, outside the soil model's slip range and the
        quasi-static force balance (withheld bags 62b94e4b601a, b5507c8f9e04: slip-sinkage
        c ≈ 1.4 on a rolling-terrain climb; 9a51da3d1271: a softer soil after a change; the
        velocimeter reads −0.06 to −0.34 m/s for ≈ 1.7 s). Such a stretch (velocimeter below
        −3σ of its noise, and below −1 mm/s, with the wheels turning forward), widened by half
        the longest smoothing window (:data:`_SMOOTH_WINDOW`) on each side, is left out of
        every fit, score and test (the engine's ``valid`` masks), with a note.
        """
        s = self.series
        threshold = -max(3.0 * float(speed_noise), 1e-3)
        sliding = (s.speed < threshold) & np.all(self._wheel_rate > 0.0, axis=1)
        inside = np.ones(self._t.size, dtype=bool)
        if not np.any(sliding):
            return inside
        margin = 0.5 * _SMOOTH_WINDOW
        starts = np.flatnonzero(sliding & ~np.r_[False, sliding[:-1]])
        ends = np.flatnonzero(sliding & ~np.r_[sliding[1:], False])
        spans = []
        for a, b in zip(starts, ends, strict=True):
            inside &= ~((self._t >= self._t[a] - margin) & (self._t <= self._t[b] + margin))
            spans.append(f"{self._t[a]:.1f}–{self._t[b]:.1f} s")
        self.notes.append(
            f"the rover slid backward (velocimeter down to {float(np.min(s.speed)):.3f} m/s with the wheels "
            f"driving forward: slip beyond 1) over {', '.join(spans)}: outside the quasi-static replay; "
            f"{100.0 * float(np.mean(~inside)):.1f} % of the samples ({margin:g} s either side included) are "
            "left out of every fit, score and test"
        )
        if not np.any(inside[self._t >= self._t[0] + self.warmup]):
            raise Sim2RealError(f"{source or 'bag'}: the rover slides backward throughout; nothing to replay")
        return inside

    def _base_inputs(self, effects: Mapping[str, Mapping[str, float]]) -> dict[str, Any]:
        """Sensor-level effects undone on the measured inputs."""
        s = self.series
        bias = effects.get("load_cell_bias", {})
        b = np.array([bias.get(f"load_cell_bias_{w}", 0.0) for w in _WHEELS])
        c = float(effects.get("load_cell_crosstalk", {}).get("load_cell_crosstalk", 0.0))
        axial = s.load_axial - b
        perp = s.load_perpendicular
        if c != 0.0:
            det = 1.0 - c * c
            axial, perp = (axial - c * perp) / det, (perp - c * axial) / det
        imu = effects.get("imu_bias", {})
        accel_bias = np.array([imu.get("imu_accel_bias_x", 0.0), imu.get("imu_accel_bias_z", 0.0)])
        f = self._accel_smooth - accel_bias
        pitch = np.arctan2(-f[:, 0], f[:, 1])
        delay = float(effects.get("sensor_delay", {}).get("sensor_delay", 0.0))
        effort = self._effort_mid
        if delay != 0.0:
            t = self._t
            effort = np.column_stack([np.interp(t - delay, t, effort[:, j]) for j in range(3)])
        return {"axial": axial, "perp": perp, "pitch": pitch, "effort": effort, "accel_bias": accel_bias}

    def _geometry(self, q1: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Body-frame O → wheel centre P (N, 3, 2) and bogie-joint → wheel centre B (N, 3, 2; zero for the front)."""
        cached = getattr(self, "_geometry_cache", None)
        if cached is not None and cached[0] is q1:
            return cached[1], cached[2]
        P, B = self._geometry_of(q1)
        self._geometry_cache = (q1, P, B)
        return P, B

    def _geometry_of(self, q1: FloatArray) -> tuple[FloatArray, FloatArray]:
        n = q1.size
        P = np.zeros((n, 3, 2))
        B = np.zeros((n, 3, 2))
        for j in range(2):
            bx, bz = _rotate(q1, np.full(n, self._bogie_wheels[j, 0]), np.full(n, self._bogie_wheels[j, 1]))
            B[:, j, 0], B[:, j, 1] = bx, bz
            P[:, j, 0], P[:, j, 1] = self._joint[0] + bx, self._joint[1] + bz
        P[:, 2, 0], P[:, 2, 1] = self._front[0], self._front[1]
        return P, B

    def _body_forces(self, axial: FloatArray, perp: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Body-frame (F_x, F_z) on each wheel from its cell: R(ε − θ)(F_⊥, F_L), (N, 3) each."""
        q1 = self.series.bogie
        fx = np.empty_like(axial)
        fz = np.empty_like(axial)
        for j in range(3):
            angle = q1 if j < 2 else 0.0
            fx[:, j], fz[:, j] = _rotate(angle, perp[:, j], axial[:, j])
        return fx, fz

    def _resistive_torque(self, effort: FloatArray) -> FloatArray:
        p = self.params
        return effort - p.wheel_damping * self._wheel_rate - p.wheel_gear_inertia * self._wheel_accel

    def _gravity_moments(self, pitch: FloatArray, P: FloatArray, B: FloatArray) -> tuple[FloatArray, FloatArray]:
        """∂V/∂θ and ∂V/∂q1 (N·m) of the bogie CM and the wheels (O is the body CM)."""
        p = self.params
        g = p.gravity
        q1 = self.series.bogie
        n = q1.size
        cx, cz = _rotate(q1, np.full(n, p.bogie_cm_offset[0]), np.full(n, p.bogie_cm_offset[1]))
        # World x of body-frame vector (bx, bz) at pitch θ: bx cos θ + bz sin θ; ∂V/∂φ = −g Σ m x_world.
        cos, sin = np.cos(pitch), np.sin(pitch)

        def world_x(bx: FloatArray, bz: FloatArray) -> FloatArray:
            return bx * cos + bz * sin

        m_b, m_w = p.bogie_mass, p.wheel_mass
        d_theta = -g * (
            m_b * world_x(self._joint[0] + cx, self._joint[1] + cz)
            + m_w * sum(world_x(P[:, j, 0], P[:, j, 1]) for j in range(3))
        )
        d_bogie = -g * (m_b * world_x(cx, cz) + m_w * sum(world_x(B[:, j, 0], B[:, j, 1]) for j in range(2)))
        return d_theta, d_bogie

    def _wheel_state(
        self, base: Mapping[str, Any], effects: Mapping[str, Mapping[str, float]]
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Per wheel (N, 3): W, i, DP, δ = γ − ε from (F_L, F_⊥, τ_R) and the soil model (module docstring, 3).

        Newton on i for τ_R(W, i) = τ_R,measured, alternating with W = √(F_L² + F_⊥² − DP²);
        started from the nominal solution of the same data (cached).
        """
        soil_inputs = {k: v for k, v in effects.items() if k in _SOIL_INPUT_EFFECTS}
        cached = self._nominal_state if self._warm_series is self.series else None
        if not soil_inputs and cached is not None:
            return cached
        axial, perp = base["axial"], base["perp"]
        tau = self._resistive_torque(base["effort"]).ravel()
        force2 = (axial**2 + perp**2).ravel()
        shape = axial.shape
        sinkage = float(effects.get("slip_sinkage", {}).get("slip_sinkage_coefficient", 0.0))
        grouser = float(effects.get("grousers", {}).get("grouser_height", 0.0))
        variants = self._variants(effects, grouser)
        warm = self._warm_start if self._warm_series is self.series else None
        rows: NDArray[np.intp] | None = None
        if cached is not None and set(soil_inputs) == {"soil_change"} and len(variants) == 2:
            # Only the samples at or beyond the change differ from the nominal solution.
            weight = np.asarray(variants[1][1])
            rows = np.flatnonzero(weight > 1e-12)
            variants = [(v, np.asarray(w)[rows]) for v, w in variants]
            tau, force2 = tau[rows], force2[rows]
        sweeps: tuple[tuple[int, int], ...]
        if warm is not None:
            slip, load = (warm[0].copy(), warm[1].copy()) if rows is None else (warm[0][rows], warm[1][rows])
            sweeps = ((2, 1), (1, 1))
        else:
            slip, load = np.full(tau.size, 0.2), np.sqrt(force2)
            sweeps = ((8, 2), (3, 1), (3, 1), (3, 1))

        def forces(sel: NDArray[np.intp] | None, w: FloatArray, i: FloatArray) -> tuple[FloatArray, FloatArray]:
            use = variants if sel is None else [(v, x if np.ndim(x) == 0 else np.asarray(x)[sel]) for v, x in variants]
            return self.soil_model.forces(w, i, sinkage=sinkage, grouser_height=grouser, variants=use)

        slip, load, dp = _solve_wheels(forces, tau, force2, slip, load, sweeps)
        if rows is not None and cached is not None:
            full = [np.array(a, dtype=float).ravel() for a in cached[:3]]
            for array, value in zip(full, (load, slip, dp), strict=True):
                array[rows] = value
            load, slip, dp = full
        if warm is None and not effects and self._warm_series is None:
            self._warm_series, self._warm_start = self.series, (slip.copy(), load.copy())
        delta = np.arctan2(perp.ravel(), axial.ravel()) - np.arctan2(dp, load)
        state = (load.reshape(shape), slip.reshape(shape), dp.reshape(shape), delta.reshape(shape))
        if not soil_inputs and self._warm_series is self.series:
            self._nominal_state = state
        return state

    def _variants(
        self, effects: Mapping[str, Mapping[str, float]], grouser: float
    ) -> list[tuple[_SoilVariant | None, FloatArray | float]]:
        base = _SoilVariant(self.soil, grouser) if grouser > 0.0 else None
        change = effects.get("soil_change")
        if change:
            from vehicle_sim.effects import effects_for

            plant = effects_for("rover", {"soil_change": {k: float(v) for k, v in change.items()}}, soil=self.soil)
            if plant.soil_change_soil is not None:
                if self._soil_weights is not None:  # the change-location scan: the soil of given wheels
                    after = self._soil_weights
                else:
                    x = self._wheel_x()
                    after = (0.5 * (1.0 + np.tanh((x - float(plant.soil_change_distance)) / _BLEND_WIDTH))).ravel()
                return [(base, 1.0 - after), (_SoilVariant(plant.soil_change_soil, grouser), after)]
        return [(base, 1.0)]

    def _wheel_x(self) -> FloatArray:
        """World x of each wheel centre (N, 3): O from 0 at the start (velocimeter integrated) plus the offset."""
        if not hasattr(self, "_wheel_x_cache"):
            base = self._base_inputs({})
            pitch = base["pitch"]
            vx = self._speed_smooth * np.cos(pitch)
            x0 = np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * np.diff(self._t))])
            P, _ = self._geometry(self.series.bogie)
            offset = P[:, :, 0] * np.cos(pitch)[:, None] + P[:, :, 1] * np.sin(pitch)[:, None]
            self._wheel_x_cache = x0[:, None] + offset
        out: FloatArray = self._wheel_x_cache
        return out

    # --- prediction -----------------------------------------------------------

    def _channels_for(
        self, effects: Mapping[str, Mapping[str, float]], series: RoverSeries | None = None
    ) -> tuple[dict[str, FloatArray], dict[str, FloatArray]]:
        """(measured, predicted) of every channel with ``effects``."""
        if series is not None:
            saved = self.series, self._t
            self.series = series
            self._prepare()
        try:
            return self._compute(effects)
        finally:
            if series is not None:
                self.series, self._t = saved
                self._prepare()

    def _body_velocity(
        self, slip: FloatArray, delta: FloatArray, pitch_rate: FloatArray, P: FloatArray, B: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Each wheel's estimate of the body-frame velocity of O, (ẋ0^R, ż0^R), (N, 3) each (module docstring, 3)."""
        s = self.series
        spin = self._wheel_rate + pitch_rate[:, None]
        spin[:, :2] += self._bogie_rate[:, None]
        rim = self.params.wheel_radius * spin
        centre = np.where(slip >= 0.0, rim * (1.0 - slip), rim / (1.0 + np.minimum(slip, 0.0) + 1e-12))
        phi = delta.copy()
        phi[:, :2] += s.bogie[:, None]
        vx = centre * np.cos(phi) - pitch_rate[:, None] * P[:, :, 1]
        vz = -centre * np.sin(phi) + pitch_rate[:, None] * P[:, :, 0]
        vx[:, :2] -= self._bogie_rate[:, None] * B[:, :2, 1]
        vz[:, :2] += self._bogie_rate[:, None] * B[:, :2, 0]
        return vx, vz

    def _compute(
        self, effects: Mapping[str, Mapping[str, float]]
    ) -> tuple[dict[str, FloatArray], dict[str, FloatArray]]:
        s, p = self.series, self.params
        base = self._base_inputs(effects)
        pitch = base["pitch"]
        P, B = self._geometry(s.bogie)
        fx, fz = self._body_forces(base["axial"], base["perp"])
        fx_raw, fz_raw = self._body_forces(s.load_axial, s.load_perpendicular)
        m = p.total_mass
        bias = base["accel_bias"]
        gyro_bias = float(effects.get("imu_bias", {}).get("imu_gyro_bias", 0.0))
        pred: dict[str, FloatArray] = {}
        meas: dict[str, FloatArray] = {}
        meas["accel_x"], meas["accel_z"] = s.accel[:, 0], s.accel[:, 1]
        pred["accel_x"] = fx.sum(axis=1) / m + bias[0]
        pred["accel_z"] = fz.sum(axis=1) / m + bias[1]
        # Soil: per-wheel slip and contact angle (independent of the pitch rate).
        load, slip, dp, delta = self._wheel_state(base, effects)
        # Pitch from gravity: the accelerometer minus the body acceleration, which the wheels' velocities give
        # (a first pass with the quasi-static pitch; the dynamic part reaches 1e-2 m/s² at a soil change).
        pitch_rate = _savgol(np.unwrap(pitch), self._window, 1, self.dt)
        vx, vz = self._body_velocity(slip, delta, pitch_rate, P, B)
        ax = _savgol(vx.mean(axis=1), self._accel_window, 1, self.dt)
        az = _savgol(vz.mean(axis=1), self._accel_window, 1, self.dt)
        f = s.accel - bias
        pitch = _savgol(np.unwrap(np.arctan2(-(f[:, 0] - ax), f[:, 1] - az)), self._window, 0, self.dt)
        pitch_rate = _savgol(pitch, self._window, 1, self.dt)
        vx, vz = self._body_velocity(slip, delta, pitch_rate, P, B)
        meas["pitch_rate"] = s.gyro
        pred["pitch_rate"] = pitch_rate + gyro_bias

        # Moments: load-cell side as the raw cells read it; effort side from the wheel rows.
        def cross(vec: FloatArray, fxj: FloatArray, fzj: FloatArray) -> FloatArray:
            result: FloatArray = vec[..., 1] * fxj - vec[..., 0] * fzj
            return result

        tau_r = self._resistive_torque(base["effort"])
        d_theta, d_bogie = self._gravity_moments(pitch, P, B)
        body_raw = cross(P, fx_raw, fz_raw).sum(axis=1)
        body_true = cross(P, fx, fz).sum(axis=1)
        bogie_raw = cross(B[:, :2], fx_raw[:, :2], fz_raw[:, :2]).sum(axis=1)
        bogie_true = cross(B[:, :2], fx[:, :2], fz[:, :2]).sum(axis=1)
        meas["moment_body"] = body_raw
        pred["moment_body"] = tau_r.sum(axis=1) + d_theta + (body_raw - body_true)
        meas["moment_bogie"] = bogie_raw
        pred["moment_bogie"] = tau_r[:, :2].sum(axis=1) + d_bogie + (bogie_raw - bogie_true)

        meas["velocimeter"] = s.speed
        pred["velocimeter"] = vx.mean(axis=1)
        zeros = np.zeros_like(s.speed)
        meas["vz_front_middle"] = zeros
        pred["vz_front_middle"] = vz[:, 2] - vz[:, 1]
        meas["vz_middle_rear"] = zeros
        pred["vz_middle_rear"] = vz[:, 1] - vz[:, 0]
        self._last_state = {"load": load, "slip": slip, "drawbar_pull": dp, "delta": delta}
        for name, value in pred.items():
            if not np.all(np.isfinite(value)):
                pred[name] = np.where(np.isfinite(value), value, 0.0)
        return meas, pred

    def _build_channels(self, replicates: int, seed: int) -> None:
        meas, pred = self._channels_for({})
        rng = np.random.default_rng(seed)
        s = self.series
        nz = self.noise
        spread: dict[str, list[FloatArray]] = {k: [] for k in meas}
        for _ in range(max(0, replicates)):
            noisy = dataclasses.replace(
                s,
                accel=s.accel + nz.get("acceleration", 0.0) * rng.standard_normal(s.accel.shape),
                gyro=s.gyro + nz.get("pitch_rate", 0.0) * rng.standard_normal(s.gyro.shape),
                bogie=s.bogie + nz.get("bogie_angle", 0.0) * rng.standard_normal(s.bogie.shape),
                wheel_angle=s.wheel_angle + nz.get("wheel_angle", 0.0) * rng.standard_normal(s.wheel_angle.shape),
                speed=s.speed + nz.get("forward_speed", 0.0) * rng.standard_normal(s.speed.shape),
                load_axial=s.load_axial + nz.get("load_cell", 0.0) * rng.standard_normal(s.load_axial.shape),
                load_perpendicular=s.load_perpendicular
                + nz.get("load_cell", 0.0) * rng.standard_normal(s.load_perpendicular.shape),
            )
            m2, p2 = self._channels_for({}, noisy)
            for k in meas:
                spread[k].append((m2[k] - p2[k]) - (meas[k] - pred[k]))
        use = self._t >= self._t[0] + self.warmup
        units = {
            "accel_x": ("imu linear_acceleration.x", "m/s²"),
            "accel_z": ("imu linear_acceleration.z", "m/s²"),
            "pitch_rate": ("imu angular_velocity.y", "rad/s"),
            "moment_body": ("wheel/*/load force.z, force.x: moment about O (vs joint_states effort)", "N·m"),
            "moment_bogie": ("wheel/{rear,middle}/load: moment about the bogie joint (vs effort)", "N·m"),
            "velocimeter": ("velocimeter twist.linear.x", "m/s"),
            "vz_front_middle": ("wheel/{front,middle}/load + joint_states: body z velocity front − middle", "m/s"),
            "vz_middle_rear": ("wheel/{middle,rear}/load + joint_states: body z velocity middle − rear", "m/s"),
        }
        channels = []
        for name in meas:
            # One more noise realisation through the replay changes the residual by what one realisation
            # does: its spread is the propagated noise. The replay's smoothing colours it, so σ is the white
            # level that bounds it in every octave band of the noise tests, not only its variance.
            propagated = (
                _white_bound([d[use & self._inside] for d in spread[name]], 1.0 / self.dt) if spread[name] else 0.0
            )
            sigma = math.hypot(propagated, MODEL_FLOORS.get(name, 0.0))
            if not (sigma > 0.0 and math.isfinite(sigma)):
                sigma = MODEL_FLOORS.get(name, 1e-6) or 1e-6
            topic, unit = units[name]
            channels.append(Channel(name, topic, unit, sigma))
        self.channels: list[Channel] = channels
        self.times: dict[str, FloatArray] = {c.name: self._t for c in channels}
        self.valid: dict[str, NDArray[np.bool_]] = {c.name: self._inside for c in channels}
        self.measured: dict[str, FloatArray] = {k: np.asarray(v, dtype=float) for k, v in meas.items()}
        state = self._last_state if hasattr(self, "_last_state") else {}
        self.regimes: dict[str, tuple[FloatArray, FloatArray]] = {
            "forward speed (m/s)": (self._t, self._speed_smooth),
            "bogie angle (rad)": (self._t, s.bogie),
        }
        if state:
            self.regimes["mean slip (–)"] = (self._t, np.mean(state["slip"], axis=1))

    def _adapt_candidates(self, catalogue: Mapping[str, Candidate]) -> dict[str, Candidate]:
        """The catalogue's candidates; the soil-change distance starts where the bag's residual says.

        The distance's bounds stay the catalogue's; its start (``off``, immaterial
        while the soil scales are 1) is the location :meth:`_change_location`
        finds on the wheel-centre positions the bag covers, 5 mm apart, else the
        middle of the wheels' travel.
        """
        out = dict(catalogue)
        if "soil_change" in out:
            found: float | None = None
            x = self._wheel_x()
            use = (self._t >= self._t[0] + self.warmup) & self._inside
            lo = max(0.0, float(np.min(x[use])))
            hi = min(10.0, float(np.max(x[use])))
            if hi > lo:
                count = int(min(200, max(2, math.ceil((hi - lo) / 5e-3) + 1)))
                found = self._change_location(np.linspace(lo, hi, count))
            params = []
            for prm in out["soil_change"].parameters:
                if prm.name == "soil_change_distance" and hi > lo:
                    if found is not None:
                        params.append(FitParameter(prm.name, prm.unit, found, prm.bounds, _LOCATION_SCALE))
                    else:
                        mid = 0.5 * (lo + hi)
                        params.append(FitParameter(prm.name, prm.unit, mid, prm.bounds, max(0.25 * (hi - lo), 1e-3)))
                else:
                    params.append(prm)
            out["soil_change"] = Candidate("soil_change", tuple(params), out["soil_change"].description)
        return out

    def _change_location(self, grid: FloatArray) -> float | None:
        """Where along the path a soil change would best explain the nominal residual (a start for the fit).

        A linearised change-point scan on the training part of the default
        split (:func:`~terrain_analysis.sim2real.attribution.held_out_mask`;
        the held-out part is never looked at). For each soil-change scale k
        (at its typical value) and wheel j, J_jk is the change of every channel
        (in units of σ) when wheel j alone runs on that soil over the whole
        bag (12 replays). A change at d then predicts the nominal residual
        r ≈ Σ_k β_k Σ_j [x_j ≥ d] J_jk, linear in β (the same soil under every
        wheel, as the plant's); the start is the d of the grid with the lowest
        residual sum of squares, refined by the replay itself
        (:meth:`_refine_location`). The fit's own gradient cannot move d far: the
        cost depends on it only through the few samples at the wheels'
        crossings, and it is flat while the scales are 1 (measured on the
        withheld-effect suite's six soil-change bags: started in the middle of
        the travel, the fit stayed 10–44 cm from the change on three; the
        linearised scan alone starts it within 14 mm on five, 12 cm off on the
        sixth, where a loose soil meets a sharp step and the linearisation
        prefers the later onset of the largest residual; with the refinement
        within 8 mm on all six, 1 mm on that one). None: nothing to scan.
        """
        from terrain_analysis.sim2real.attribution import AttributionSettings, held_out_mask
        from vehicle_sim.effects import CATALOGUE

        train, _ = held_out_mask(cast(ReplayModel, self), AttributionSettings())
        use = train[self.channels[0].name]
        if np.count_nonzero(use) < 10:
            return None
        effect = CATALOGUE["rover"]["soil_change"]
        names = [c.name for c in self.channels]
        sigma = np.array([c.noise_std for c in self.channels])
        _, nominal = self._compute({})
        residual = np.stack([(self.measured[c] - nominal[c])[use] for c in names], axis=1) / sigma
        scales = [p for p in effect.parameters if p.name != "soil_change_distance"]
        jac = np.zeros((3, len(scales), int(np.count_nonzero(use)), len(names)))
        values = {p.name: p.off for p in effect.parameters}
        try:
            for k, prm in enumerate(scales):
                changed = {**values, prm.name: prm.typical}
                for j in range(3):
                    weights = np.zeros((self._t.size, 3))
                    weights[:, j] = 1.0
                    self._soil_weights = weights.ravel()
                    _, pred = self._compute({"soil_change": changed})
                    jac[j, k] = np.stack([(pred[c] - nominal[c])[use] for c in names], axis=1) / sigma
        finally:
            self._soil_weights = None
        x = self._wheel_x()[use]
        target = residual.ravel()
        rss = np.full(grid.size, np.inf)
        for m, d in enumerate(grid):
            design = np.einsum("nj,jknc->nck", (x >= d).astype(float), jac).reshape(-1, len(scales))
            if not np.any(design):
                continue
            beta, *_ = np.linalg.lstsq(design, target, rcond=None)
            rss[m] = float(np.sum((target - design @ beta) ** 2))
        if not np.any(np.isfinite(rss)):
            return None
        return self._refine_location(float(grid[int(np.argmin(rss))]), grid, scales, train)

    def _refine_location(
        self, start: float, grid: FloatArray, scales: Sequence[Any], train: Mapping[str, NDArray[np.bool_]]
    ) -> float:
        """The linearised scan's location ``start`` corrected by the replay's own training cost.

        The linearisation (each wheel's response to a typical soil, scaled) misjudges a soil
        far from the typical one: a loose soil meeting a sharp step puts its lowest RSS 12 cm
        beyond the change. The replay's training cost is sharp at the change once the soil
        scales are right (a change put too early sends the wheels before it into the wrong
        soil; too late costs the samples in between). So the scales are fitted with the
        distance held at ``start`` (the engine's screen of starts: off, ± the typical change,
        an 11-point grid of each scale; then at most :data:`_LOCATION_NFEV` trust-region
        evaluations), the distance is scanned with them over the points of ``grid`` within
        :data:`_LOCATION_WINDOW`, and the two steps repeat from the lowest cost until the
        location stays (at most :data:`_LOCATION_ROUNDS` rounds: scales fitted 12 cm from the
        change put it 3 cm early on the test's rolling-terrain run, the second round on it).
        """
        from scipy import optimize

        names = [c.name for c in self.channels]
        sigma = {c.name: c.noise_std for c in self.channels}
        measured = {c: self.measured[c][train[c]] for c in names}

        def residual(distance: float, v: FloatArray) -> FloatArray:
            values = {"soil_change_distance": distance, **{p.name: float(x) for p, x in zip(scales, v, strict=True)}}
            pred = self._compute({"soil_change": values})[1]
            r = np.concatenate([(measured[c] - pred[c][train[c]]) / sigma[c] for c in names])
            return np.where(np.isfinite(r), r, 1e3)

        lo = np.array([p.fit_range[0] for p in scales])
        hi = np.array([p.fit_range[1] for p in scales])
        off = np.array([p.off for p in scales])
        typical = np.abs(np.array([p.typical for p in scales]) - off)
        span = hi - lo
        screen = [off]
        for k in range(len(scales)):
            for v in (off[k] + typical[k], off[k] - typical[k], *np.linspace(lo[k], hi[k], 11)):
                screen.append(np.where(np.arange(len(scales)) == k, v, off))
        costs = [float(np.sum(residual(start, np.clip(s, lo, hi)) ** 2)) for s in screen]
        fitted = screen[int(np.argmin(costs))]
        location = start
        for _ in range(_LOCATION_ROUNDS):
            first = np.clip(fitted, lo + 1e-6 * span, hi - 1e-6 * span)
            try:
                fitted = optimize.least_squares(
                    lambda v, d=location: residual(d, v),
                    first,
                    bounds=(lo, hi),
                    x_scale=typical,
                    max_nfev=_LOCATION_NFEV,
                    diff_step=1e-3,
                ).x
            except (ValueError, FloatingPointError):  # pragma: no cover - defensive
                fitted = first
            near = [float(d) for d in grid if abs(d - location) <= _LOCATION_WINDOW]
            if not near:
                break
            cost = [float(np.sum(residual(d, fitted) ** 2)) for d in near]
            moved = near[int(np.argmin(cost))]
            if moved == location:
                break
            location = moved
        return location

    def predict(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> dict[str, FloatArray]:
        """Predicted channels with ``effects`` added (``{}``: nominal); no nuisance parameters."""
        _, pred = self._compute(effects)
        return pred


# ---------------------------------------------------------------------------
# Building
# ---------------------------------------------------------------------------


def _config_values(config: str | Path | None) -> tuple[dict[str, Any], dict[str, Any]]:
    from terrain_estimation.vehicles import estimator_parameters, get_vehicle
    from vehicle_sim.ros.registry import get_simulator, simulator_parameters

    est = estimator_parameters(get_vehicle("rover"), config)
    sim = simulator_parameters(get_simulator("rover"), config)
    return est, sim


def _soil_from(values: Mapping[str, Any]) -> Any:
    from vehicle_sim.terrain.wong_reece import WongReeceSoil

    fields = [f.name for f in dataclasses.fields(WongReeceSoil)]
    return WongReeceSoil(**{name: float(values[f"soil.{name}"]) for name in fields})


def build_model_from_series(
    series: RoverSeries,
    *,
    config: str | Path | None = None,
    params: RoverParams | None = None,
    soil: Any = None,
    warmup: float = 3.0,
    source: str = "",
    progress: Progress = None,
) -> RoverReplay:
    """The replay model of already-read sensor streams (vehicle, soil and noise from the config)."""
    from terrain_estimation.ros.rover import vehicle_params

    est, sim = _config_values(config)
    if int(est["estimator.load_cell_axes"]) != 2:
        raise Sim2RealError(
            "estimator.load_cell_axes = 1: the rover replay needs two-axis load cells (force.x and force.z); "
            "with one axis W, DP and the contact angle of a wheel are not separable"
        )
    noise = {
        "acceleration": float(est["noise.acceleration"]),
        "pitch_rate": float(est["noise.pitch_rate"]),
        "bogie_angle": float(est["noise.bogie_angle"]),
        "wheel_angle": float(est["noise.wheel_angle"]),
        "forward_speed": float(est["noise.forward_speed"]),
        "load_cell": float(est["noise.load_cell"]),
    }
    if progress is not None:
        progress(f"building the rover replay ({series.t.size} samples)")
    return RoverReplay(
        series,
        params or vehicle_params(est),
        soil if soil is not None else _soil_from(sim),
        warmup=warmup,
        noise=noise,
        source=source,
    )


def build_model(
    bag: str | Path,
    *,
    config: str | Path | None = None,
    namespace: str | None = None,
    progress: Progress = None,
    warmup: float = 3.0,
) -> RoverReplay:
    """The replay model of a rover bag (CONTRACT.md rover topics) for the attribution engine.

    Args:
        bag: rosbag2 directory.
        config: the rover config (default ``config/rover.yaml``): vehicle, noise, soil, joint names.
        namespace: the bag's namespace (default ``/rover``).
        progress: called with progress lines.
        warmup: seconds left out at the start.

    Raises:
        Sim2RealError: missing topic or joint, non-finite values, single-axis load cells, too short.
    """
    est, _ = _config_values(config)
    joints = {
        "bogie": str(est["joints.bogie"]),
        "rear": str(est["joints.rear_wheel"]),
        "middle": str(est["joints.middle_wheel"]),
        "front": str(est["joints.front_wheel"]),
    }
    if progress is not None:
        progress(f"reading {bag}")
    series = read_rover_bag(bag, namespace=namespace or "/rover", joints=joints)
    return build_model_from_series(series, config=config, warmup=warmup, source=str(bag), progress=progress)
