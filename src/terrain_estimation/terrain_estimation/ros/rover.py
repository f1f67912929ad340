"""Rocker-bogie terrain-response estimator (Estimators 1 + 2|3, online terrain model): topics and adapter.

Topics (CONTRACT.md, "Rocker-bogie rover"), relative to the vehicle namespace:

* in: ``imu`` (sensor_msgs/Imu: ``linear_acceleration.x``, ``.z`` = specific
  force along the body axes, gravity included, REP 145; ``angular_velocity.y``
  = pitch rate), ``joint_states`` (sensor_msgs/JointState: ``position`` of the
  joints ``bogie`` (q1) and ``rear_wheel``, ``middle_wheel``,
  ``front_wheel`` (q2..q4, relative to their carrier link), ``effort`` of
  the three wheels = applied wheel torque τ_W; ``velocity`` is not used: the
  rates are encoder differences over each step, eq. 63), ``velocimeter``
  (geometry_msgs/TwistStamped: ``twist.linear.x``), ``wheel/front/load``,
  ``wheel/middle/load``, ``wheel/rear/load`` (geometry_msgs/WrenchStamped in
  the cell's frame: ``force.z`` = F_L along the sensing axis, ``force.x`` =
  F_⊥ along the carrier's forward axis, read only with
  ``estimator.load_cell_axes: 2``). Joint names are parameters.
* out: ``wheel_terrain`` (terrain_msgs/WheelTerrainArray) — one message per
  estimator step (5 Hz), ``wheels`` in the order **rear, middle, front**
  ([RB] wheels 1, 2, 3; :data:`~terrain_estimation.models.rover.WHEELS`),
  each named in its ``wheel`` field. ``contact_angle`` is γ, the angle of the
  terrain tangent under the wheel below the world horizontal (rad, positive
  where the terrain descends forward; eqs. 79–82), not the Wong–Reece entry
  angle θ0. Variances are the filters' posterior variances.
  ``terrain_model`` (terrain_msgs/TerrainResponseModel) — the 2nd-order
  DP(W, i) and τ_R(W, i) fitted online (C.7); coefficients in the order of
  :func:`~terrain_estimation.models.terrain_response.polynomial_exponents`
  (for total degree d = 0..order, for k = d..0: the term i^k W^(d−k); order 2:
  ``[1, i, W, i², i·W, W²]``), validity region = the fitted samples' (i, W)
  range. Its error: ``dp_covariance``/``tau_covariance`` (n × n, row-major) of
  the coefficients, ``*_holdout_rms`` on samples the fit did not see,
  ``*_estimate_rms`` the estimates' own stated error, and
  ``*_prediction_rms`` over the validity region
  (:mod:`~terrain_estimation.models.terrain_response_error`); a new model
  moves the last by at most ``terrain_model.max_jump`` of its stated σ.

**When terrain_model is published.** Every estimate (after
``terrain_model.settle_time`` from a filter (re)initialisation) goes into a
:class:`~terrain_estimation.estimators.rover.TerrainResponseAccumulator`,
which averages it into one sample per wheel per ``terrain_model.sample_period``
(2 s) and gates the sample on terrain curvature (κ < 1/``vehicle.wheelbase``)
and speed. Each time ``terrain_model.fit_every`` new averaged samples have
been kept and at least ``terrain_model.min_samples`` are held, the models are
refitted and one message is published (none when the fit is rank deficient).
A sample period closes when the first estimate of the next one arrives, so
with the defaults (2 s periods, 12 samples = 4 periods × 3 wheels, 2 s
settle) the first model is published about 10 s into a run. A model is
stamped with the mean time of its newest sample period (≈ 9 s for that
first one), so its stamp says how recent the data are.

**Never NaN.** Every numeric input field is checked before it reaches the
core; a non-finite value, a missing joint, a wrong array length or a stamp
out of order is rejected and counted in the diagnostics as
``"<topic>: <field> = <value> …"``. The core keeps every published float
finite. Before the adapter, the node checks every message too (frames
``frames.<key>``, stamps, finite fields, IMU covariances and gravity:
:mod:`terrain_estimation.ros.validation`); while a stream is silent for
longer than ``timeouts.<key>`` the diagnostics WARN and the estimate holds
(:data:`ON_TIMEOUT`).

The parameters and the core configuration they make are in
:mod:`terrain_estimation.ros.rover_params`; the names other modules import from here are
re-exported (``name as name``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any

from geometry_msgs.msg import TwistStamped, WrenchStamped
from sensor_msgs.msg import Imu, JointState

from terrain_estimation.estimators.rover import (
    RoverEstimate,
    RoverTerrainEstimator,
    TerrainResponseAccumulator,
    TerrainResponseFit,
)
from terrain_estimation.estimators.rover_diagnostics import FaultCheck, consistency_dof
from terrain_estimation.models.rover import WHEELS
from terrain_estimation.params import ParamValue
from terrain_estimation.ros.adapters import AdapterHealth, TopicSpec
from terrain_estimation.ros.parameters import divergence_errors, input_frame, namespaced_frame
from terrain_estimation.ros.parameters import float_value as _f
from terrain_estimation.ros.rover_params import CONFIG_PARAMETERS as CONFIG_PARAMETERS
from terrain_estimation.ros.rover_params import NOT_GIVEN as NOT_GIVEN
from terrain_estimation.ros.rover_params import ON_TIMEOUT, estimator_config, terrain_response_config
from terrain_estimation.ros.rover_params import PARAMETERS as PARAMETERS
from terrain_estimation.ros.rover_params import VEHICLE_SPECS_ROVER as VEHICLE_SPECS_ROVER
from terrain_estimation.ros.rover_params import specs_for as specs_for
from terrain_estimation.ros.rover_params import vehicle_params as vehicle_params
from terrain_estimation.ros.time import sec_to_stamp, stamp_to_ns
from terrain_estimation.ros.validation import STANDARD_GRAVITY
from terrain_msgs.msg import TerrainResponseModel, WheelTerrain, WheelTerrainArray

__all__ = ["WHEEL_ORDER", "RoverAdapter", "estimate_to_msg", "fit_to_msg", "make_adapter"]

#: Order of ``WheelTerrainArray.wheels`` (published and ground truth): [RB] wheels 1, 2, 3.
WHEEL_ORDER: tuple[str, str, str] = WHEELS


def estimate_to_msg(e: RoverEstimate, frame_id: str) -> WheelTerrainArray:
    """The contract's WheelTerrainArray of one estimate, wheels in :data:`WHEEL_ORDER` (floats finite by the core)."""
    msg = WheelTerrainArray(
        wheels=[
            WheelTerrain(
                wheel=w.wheel,
                slip=w.slip,
                slip_variance=w.slip_variance,
                normal_load=w.normal_load,
                normal_load_variance=w.normal_load_variance,
                drawbar_pull=w.drawbar_pull,
                drawbar_pull_variance=w.drawbar_pull_variance,
                resistive_torque=w.resistive_torque,
                resistive_torque_variance=w.resistive_torque_variance,
                contact_angle=w.contact_angle,
                contact_angle_variance=w.contact_angle_variance,
            )
            for w in e.wheels
        ],
        settled=e.settled,
    )
    msg.header.stamp = sec_to_stamp(e.t)
    msg.header.frame_id = frame_id
    return msg


def fit_to_msg(fit: TerrainResponseFit, frame_id: str) -> TerrainResponseModel:
    """terrain_msgs/TerrainResponseModel of one fit, stamped with its newest sample's time."""
    msg = TerrainResponseModel(
        order=fit.order,
        dp_coefficients=[float(c) for c in fit.dp_coefficients],
        tau_coefficients=[float(c) for c in fit.tau_coefficients],
        slip_min=fit.slip_min,
        slip_max=fit.slip_max,
        load_min=fit.load_min,
        load_max=fit.load_max,
        samples=fit.samples,
        dp_rms=fit.dp_rms,
        tau_rms=fit.tau_rms,
        dp_covariance=[float(c) for c in fit.dp_covariance.ravel()],
        tau_covariance=[float(c) for c in fit.tau_covariance.ravel()],
        dp_holdout_rms=fit.dp_holdout_rms,
        tau_holdout_rms=fit.tau_holdout_rms,
        dp_estimate_rms=fit.dp_estimate_rms,
        tau_estimate_rms=fit.tau_estimate_rms,
        dp_prediction_rms=fit.dp_prediction_rms,
        tau_prediction_rms=fit.tau_prediction_rms,
        validation_samples=fit.validation_samples,
    )
    msg.header.stamp = sec_to_stamp(fit.t)
    msg.header.frame_id = frame_id
    return msg


_MAX_REJECT_REASONS = 64
"""Distinct rejection reasons kept with their value; beyond, the value is dropped from the key (bounded diagnostics)."""

_ZERO_PERPENDICULAR_WARN = 50
#: The innovation fault check (estimators.rover_diagnostics.FaultCheck): window (s of stamps) and the
#: two-sided band probability (upper tail 5e-5 per update: on the simulated terrains 1 and 4 the largest 2-s mean
#: of a nominal run was 1.5-1.8x the dof).
_FAULT_WINDOW_S = 2.0
_FAULT_PROBABILITY = 0.9999
"""Load-cell messages in a row with force.x exactly 0 on every wheel that raise the single-axis warning."""


class RoverAdapter:
    """Messages ↔ :class:`RoverTerrainEstimator` and :class:`TerrainResponseAccumulator` for one rover side."""

    def __init__(self, values: Mapping[str, ParamValue], namespace: str) -> None:
        self.config = estimator_config(values)
        self.model_config = terrain_response_config(values)
        self.model_enabled = bool(values["terrain_model.enabled"])
        self.settle_time = _f(values, "terrain_model.settle_time")
        self.fit_every = int(values["terrain_model.fit_every"])
        self.estimator = RoverTerrainEstimator(self.config)
        self.accumulator = TerrainResponseAccumulator(self.model_config)
        self.frame_id = namespaced_frame(namespace, str(values["frames.base_link"]))
        # joint_states names in WHEELS order (rear, middle, front).
        self.bogie_joint = str(values["joints.bogie"])
        self.wheel_joints = tuple(str(values[f"joints.{w}_wheel"]) for w in WHEELS)
        self.two_axis = self.config.load_cell_axes == 2
        joints = (self.bogie_joint, *self.wheel_joints)
        # A cell above a hub carries part of the side's weight; no real shock puts more on it than the whole
        # side's mass at the largest acceleration an accelerometer may read (input.max_acceleration): beyond
        # that a reading is a glitch (a 1e300 N sample would otherwise enter the window means and the filter).
        side_mass = self.config.rover.total_mass
        max_force = side_mass * _f(values, "input.max_acceleration") * STANDARD_GRAVITY
        cell_fields = ("wrench.force.z", "wrench.force.x") if self.two_axis else ("wrench.force.z",)
        cell_bounds = tuple(
            (f, max_force, f"the side's mass {side_mass:.3g} kg at input.max_acceleration, N") for f in cell_fields
        )

        def spec(key: str, topic: str, msg_type: type, **checks: Any) -> TopicSpec:
            return TopicSpec(
                key,
                topic,
                msg_type,
                frame_id=input_frame(values, namespace, key),
                timeout=_f(values, f"timeouts.{key}"),
                on_timeout=ON_TIMEOUT[key],
                **checks,
            )

        self.inputs: Sequence[TopicSpec] = (
            spec(
                "imu",
                "imu",
                Imu,
                fields=("linear_acceleration.x", "linear_acceleration.z", "angular_velocity.y"),
                covariances=("linear_acceleration_covariance", "angular_velocity_covariance"),
                gravity_fields=("linear_acceleration.x", "linear_acceleration.z"),
                gravity=_f(values, "vehicle.gravity"),
            ),
            spec(
                "joint_states",
                "joint_states",
                JointState,
                fields=(*(f"position[{j}]" for j in joints), *(f"effort[{j}]" for j in self.wheel_joints)),
            ),
            spec("velocimeter", "velocimeter", TwistStamped, fields=("twist.linear.x",)),
            *(
                spec(
                    f"load_{w}",
                    f"wheel/{w}/load",
                    WrenchStamped,
                    fields=cell_fields,
                    bounds=cell_bounds,
                )
                for w in ("front", "middle", "rear")
            ),
        )
        self.outputs: Sequence[TopicSpec] = (
            TopicSpec(
                "wheel_terrain",
                "wheel_terrain",
                WheelTerrainArray,
                "estimate",
                truth_fields=tuple(
                    f"wheels[{i}].{q}"
                    for i in range(len(WHEELS))
                    for q in ("slip", "normal_load", "drawbar_pull", "resistive_torque")
                ),
            ),
            TopicSpec("terrain_model", "terrain_model", TerrainResponseModel, "estimate"),
        )
        self.reset()

    def reset(self) -> None:
        self.estimator.reset()
        self.accumulator.reset()
        # NIS over the channels whose S is sensor noise plus state uncertainty (slips, load cells, and with two-axis
        # cells the side's force balance; estimators.rover_diagnostics says which are left out and why):
        # chi-square with 11 (two-axis) or 6 dof.
        dof = consistency_dof(self.estimator.config.load_cell_axes)
        self.health = AdapterHealth(nis_dof=dof)
        self._fault_check = FaultCheck(
            dof, max(1, math.ceil(_FAULT_WINDOW_S * self.estimator.config.estimator_rate_hz - 1e-9)), _FAULT_PROBABILITY
        )
        self._fault_warning: str | None = None
        self._settled_from: float | None = None
        self._buckets_at_fit = 0
        self._zero_perpendicular = dict.fromkeys(WHEELS, 0)
        self._last_stamp: dict[str, float] = {}
        self.fits_published = 0

    # -- rejections ----------------------------------------------------------------
    def _reject(self, topic: str, field: str, value: Any, problem: str) -> None:
        reason = f"{topic}: {field} = {value!r} {problem}"
        if reason not in self.health.rejected and len(self.health.rejected) >= _MAX_REJECT_REASONS:
            reason = f"{topic}: {field} {problem}"
        self.health.reject(reason)

    def _finite(self, topic: str, fields: Sequence[tuple[str, Any]]) -> bool:
        for name, value in fields:
            v = float(value)
            if not math.isfinite(v):
                self._reject(topic, name, v, "is not finite")
                return False
        return True

    def _call(self, topic: str, stamp: float, call: Any, *args: Any) -> None:
        """Pass one sample of ``topic`` to the core if its stamp is after the topic's previous one."""
        previous = self._last_stamp.get(topic)
        if previous is not None and stamp <= previous:
            self._reject(topic, "header.stamp", stamp, "is not after the previous sample's")
            return
        try:
            call(stamp, *args)
        except ValueError as exc:  # anything else the core refuses, in its words
            self.health.reject(f"{topic}: {exc}")
            return
        self._last_stamp[topic] = stamp

    # -- adapter protocol ------------------------------------------------------------
    def handle(self, key: str, msg: Any) -> list[tuple[str, Any]]:
        t = stamp_to_ns(msg.header.stamp) * 1e-9
        if key == "imu":
            acc = msg.linear_acceleration
            self._on_imu(t, acc.x, acc.z, msg.angular_velocity.y)
        elif key == "joint_states":
            self._on_joints(t, msg)
        elif key == "velocimeter":
            self._on_velocimeter(t, msg.twist.linear.x)
        elif key.startswith("load_"):
            force = msg.wrench.force
            self._on_load_cell(t, key[len("load_") :], force.z, force.x)
        else:
            return []
        return self._drain()

    @property
    def field_handlers(self) -> Mapping[str, Callable[[int, Sequence[float]], list[tuple[str, Any]]]]:
        """Input key -> the handler taking a message's stamp (ns) and its checked fields (the TopicSpec's
        ``fields`` then ``gravity_fields``, in order) in place of the message: :meth:`handle` of that message,
        without it (the offline replay decodes these inputs in bulk, :mod:`terrain_estimation.tools.estimate_replay`).
        ``joint_states`` (names and arrays of any length) is handled as a message."""
        handlers: dict[str, Callable[[int, Sequence[float]], list[tuple[str, Any]]]] = {
            "imu": self.handle_imu,
            "velocimeter": self.handle_velocimeter,
        }
        for wheel in WHEELS:
            handlers[f"load_{wheel}"] = partial(self.handle_load_cell, wheel)
        return handlers

    def handle_imu(self, stamp_ns: int, values: Sequence[float]) -> list[tuple[str, Any]]:
        """:meth:`handle` of an IMU sample given by its stamp and ``linear_acceleration.x``, ``.z``,
        ``angular_velocity.y``."""
        self._on_imu(stamp_ns * 1e-9, values[0], values[1], values[2])
        return self._drain()

    def handle_velocimeter(self, stamp_ns: int, values: Sequence[float]) -> list[tuple[str, Any]]:
        """:meth:`handle` of a velocimeter sample given by its stamp and ``twist.linear.x``."""
        self._on_velocimeter(stamp_ns * 1e-9, values[0])
        return self._drain()

    def handle_load_cell(self, wheel: str, stamp_ns: int, values: Sequence[float]) -> list[tuple[str, Any]]:
        """:meth:`handle` of ``wheel``'s load-cell sample given by its stamp and ``wrench.force.z`` (then
        ``wrench.force.x`` with two-axis cells)."""
        self._on_load_cell(stamp_ns * 1e-9, wheel, values[0], values[1] if self.two_axis else None)
        return self._drain()

    def _on_imu(self, t: float, ax: Any, az: Any, gy: Any) -> None:
        fields = [("linear_acceleration.x", ax), ("linear_acceleration.z", az), ("angular_velocity.y", gy)]
        if self._finite("imu", fields):
            self._call("imu", t, self.estimator.add_imu, float(ax), float(az), float(gy))

    def _on_velocimeter(self, t: float, speed: Any) -> None:
        if self._finite("velocimeter", [("twist.linear.x", speed)]):
            self._call("velocimeter", t, self.estimator.add_velocimeter, float(speed))

    def _on_joints(self, t: float, msg: Any) -> None:
        topic = "joint_states"
        names = list(msg.name)
        missing = [j for j in (self.bogie_joint, *self.wheel_joints) if j not in names]
        if missing:
            self._reject(topic, "name", names, f"lacks {', '.join(missing)}")
            return
        for field in ("position", "effort"):
            n = len(getattr(msg, field))
            if n != len(names):
                self._reject(topic, f"len({field})", n, f"differs from len(name) = {len(names)}")
                return
        index = {name: k for k, name in enumerate(names)}
        bogie = float(msg.position[index[self.bogie_joint]])
        angles = [float(msg.position[index[j]]) for j in self.wheel_joints]
        torques = [float(msg.effort[index[j]]) for j in self.wheel_joints]
        fields = [(f"position[{self.bogie_joint}]", bogie)]
        fields += [(f"position[{j}]", a) for j, a in zip(self.wheel_joints, angles, strict=True)]
        fields += [(f"effort[{j}]", e) for j, e in zip(self.wheel_joints, torques, strict=True)]
        if self._finite(topic, fields):
            self._call(topic, t, self.estimator.add_joint_state, bogie, angles, torques)

    def _on_load_cell(self, t: float, wheel: str, axial: Any, perpendicular: Any) -> None:
        topic = f"wheel/{wheel}/load"
        fields = [("wrench.force.z", axial)] + ([("wrench.force.x", perpendicular)] if self.two_axis else [])
        if not self._finite(topic, fields):
            return
        if self.two_axis:
            self._zero_perpendicular[wheel] = self._zero_perpendicular[wheel] + 1 if perpendicular == 0.0 else 0
            self._call(topic, t, self.estimator.add_load_cell, wheel, float(axial), float(perpendicular))
        else:
            self._call(topic, t, self.estimator.add_load_cell, wheel, float(axial), None)

    # -- outputs -------------------------------------------------------------------------
    def _drain(self) -> list[tuple[str, Any]]:
        estimates = self.estimator.drain_estimates()
        if not estimates:
            return []
        out: list[tuple[str, Any]] = []
        h = self.health
        for e in estimates:
            h.updates += 1
            h.last_update_time = e.t
            if e.initialised:
                self._fault_check.reset()
                self._fault_warning = None
            elif e.accepted and e.settled:  # the first 2 s after a start describe the start (rover_noise.is_settled)
                h.nis.append(e.consistency_nis)
                # A fault (a load-cell offset) within 2 s of stamp time; the long window's autocorrelation time.
                tau = _nis_autocorrelation_time(h.nis)
                self._fault_warning = self._fault_check.add(e.consistency_nis, tau)
            out.append(("wheel_terrain", estimate_to_msg(e, self.frame_id)))
            fit = self._feed_model(e)
            if fit is not None:
                out.append(("terrain_model", fit_to_msg(fit, self.frame_id)))
        self._update_health(estimates[-1])
        return out

    def _feed_model(self, e: RoverEstimate) -> TerrainResponseFit | None:
        """Add one estimate to the accumulator; refit when ``fit_every`` new sample periods were kept."""
        if not self.model_enabled:
            return None
        if e.initialised:
            self._settled_from = e.t + self.settle_time
            return None
        if self._settled_from is None or e.t < self._settled_from - 1e-9:
            return None
        try:
            self.accumulator.add_estimate(e)
        except ValueError as exc:  # the core keeps estimates finite and ordered; report rather than crash
            self.health.reject(f"terrain_model: {exc}")
            return None
        used = self.accumulator.counters.buckets_used
        if used - self._buckets_at_fit < self.fit_every:
            return None
        if self.accumulator.sample_count < self.model_config.required_samples:
            return None
        self._buckets_at_fit = used
        fit = self.accumulator.fit()
        if fit is not None:
            self.fits_published += 1
        return fit

    def _update_health(self, last: RoverEstimate) -> None:
        h = self.health
        c = self.estimator.counters
        m = self.accumulator.counters
        front, middle, rear = last.wheel("front"), last.wheel("middle"), last.wheel("rear")
        h.status = (
            f"Estimator 1+{last.estimator}: slip {rear.slip:.3f}/{middle.slip:.3f}/{front.slip:.3f}, "
            f"W {rear.normal_load:.1f}/{middle.normal_load:.1f}/{front.normal_load:.1f} N (rear/middle/front)"
        )
        warnings = []
        if self.two_axis and all(n >= _ZERO_PERPENDICULAR_WARN for n in self._zero_perpendicular.values()):
            warnings.append(
                "wheel/*/load: force.x (F_perp) is exactly 0 on every cell: single-axis cells? "
                "set estimator.load_cell_axes: 1"
            )
        if self._fault_warning is not None:
            warnings.append(self._fault_warning)
        h.warnings = warnings
        h.errors = divergence_errors(self.estimator.fault, c.divergences)
        curvature = self.accumulator.last_curvature
        h.values.update(
            estimator=last.estimator,
            distance_m=last.distance,
            forward_speed=last.body.forward_speed,
            pitch=last.body.pitch,
            bogie_angle=last.body.bogie_angle,
            **{name: getattr(c, name) for name in c.__dataclass_fields__},
            model_samples=self.accumulator.sample_count,
            model_samples_required=self.model_config.required_samples,
            model_fits=m.fits,
            model_fits_published=self.fits_published,
            model_buckets=m.buckets,
            model_buckets_used=m.buckets_used,
            model_rejected_curvature=m.rejected_curvature,
            model_rejected_speed=m.rejected_speed,
            model_rejected_sparse=m.rejected_sparse,
            model_samples_dropped=m.samples_dropped,
            model_last_curvature=curvature if curvature is not None else "unknown",
        )
        history = self.accumulator.history
        if history:  # the last model's stated error and how far its fit wanted to move (issue 21)
            h.values.update(
                model_dp_prediction_rms=history[-1].dp_prediction_rms,
                model_tau_prediction_rms=history[-1].tau_prediction_rms,
                model_dp_jump=history[-1].dp_jump,
                model_step_bounded=history[-1].limited,
            )


def _nis_autocorrelation_time(values: Sequence[float]) -> float:
    """τ of the NIS values (≥ 1; 1 below 8 values), imported late as the framework does (scipy, issue 23)."""
    if len(values) < 8:
        return 1.0
    from terrain_estimation.analysis.consistency import integrated_autocorrelation_time

    return float(integrated_autocorrelation_time(list(values)))


def make_adapter(values: Mapping[str, ParamValue], namespace: str) -> RoverAdapter:
    return RoverAdapter(values, namespace)
