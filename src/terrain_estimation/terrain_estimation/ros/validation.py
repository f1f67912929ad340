"""Per-message input validation and the output finiteness check of the estimator nodes.

:class:`InputGuard` sits between a node's subscriptions and its adapter
(:class:`~terrain_estimation.ros.framework.EstimatorNode` owns one). Every
input message is checked before the adapter sees it; a message that fails a
check is dropped whole (it never reaches the filter) and counted per reason.
What is checked, per input topic (:class:`~terrain_estimation.ros.framework.TopicSpec`):

* ``header.frame_id`` equals the topic's expected frame (``frames.<key>``;
  empty: not checked);
* ``header.stamp``: not more than ``input.max_future_stamp`` ahead of the
  node's clock (when the clock runs: a sim-time node before its first
  ``/clock`` has no reference), strictly after the previous accepted stamp of
  the same topic (a repeated stamp is a duplicate, an earlier one is out of
  order);
* the numeric fields the adapter reads are finite (``velocity[wheel]`` names
  a JointState entry by joint name: a missing joint or a short array is
  rejected too);
* covariance arrays (3x3, row major) are finite, symmetric and positive
  semi-definite, unless marked not measured (first element -1, the
  sensor_msgs convention);
* accelerometers: the magnitude of the mean specific force over the last
  ``input.gravity_window`` seconds is within ``input.gravity_tolerance`` of
  the vehicle's gravity (REP 145: specific force, gravity included, in m/s²).
  A stream in g (mean ≈ 1) or with gravity removed (mean ≈ 0) is rejected
  until it is plausible again. The mean needs half a window of samples to be
  judged; the samples of that first half-window (or those of a stream that
  drifts out of the band) may have reached the filter before the verdict, so
  the first rejection of this kind asks the node to restart the estimator
  (:attr:`Rejection.restart`).

A source whose clock went back without ``/clock`` saying so (a bag looped
without ``--clock``, a sensor driver restarted) would otherwise be rejected
as out of order for ever: after ``input.restart_after_out_of_order``
consecutive out-of-order samples of one topic, each later than the one
before, the guard takes its stamps as a new time line, forgets every
topic's stamps and asks the node to restart the estimator
(:attr:`Rejection.rebase`).

Nothing is repaired: the contract fixes units and frames, and a unit or
frame guessed wrong would bias the estimate silently.
"""

from __future__ import annotations

import array
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from terrain_estimation.params import ParamValue
from terrain_estimation.ros.time import stamp_to_ns

__all__ = ["Rejection", "InputGuard", "first_nonfinite", "field_value", "STANDARD_GRAVITY"]

STANDARD_GRAVITY = 9.80665
"""[m/s^2] what an accelerometer reporting in g divides by."""

_COVARIANCE_TOLERANCE = 1e-9
"""Relative tolerance of the symmetry and eigenvalue checks (of the largest absolute entry)."""


@dataclass(frozen=True)
class Rejection:
    """Why one input message was dropped.

    Attributes:
        topic: topic name relative to the namespace (``"imu/body"``).
        field: the offending field (``"linear_acceleration.z"``, ``"header.stamp"``).
        value: the offending value, formatted.
        problem: what is wrong, without the value (so that counts stay bounded).
        restart: the estimator must restart: input of this kind may already
            have reached the filter before it was recognised.
        rebase: the stamps of a topic started a new time line: the guard has
            forgotten every stamp and the estimator must restart.
    """

    topic: str
    field: str
    value: str
    problem: str
    restart: bool = False
    rebase: bool = False

    @property
    def reason(self) -> str:
        """The counter key: topic, field and problem (no value)."""
        return f"{self.topic}: {self.field} {self.problem}"

    @property
    def text(self) -> str:
        """The log line: topic, field, value and problem."""
        return f"{self.topic}: {self.field} = {self.value} {self.problem}"


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.9g}"
    return repr(value)


def field_value(msg: Any, path: str) -> Any:
    """The value at ``path`` in ``msg``: dotted attributes, ``array[joint]`` by JointState name.

    Raises:
        LookupError: the joint is not in ``msg.name`` or the array is too short;
            its args are (field, value, problem) for a :class:`Rejection`.
    """
    obj = msg
    for part in path.split("."):
        if part.endswith("]") and "[" in part:
            attr, joint = part[:-1].split("[", 1)
            values = getattr(obj, attr)
            names = list(obj.name)
            if joint not in names:
                raise LookupError("name", repr(names)[:200], f"lacks joint {joint!r} (for {attr})")
            index = names.index(joint)
            if index >= len(values):
                raise LookupError(f"len({attr})", str(len(values)), f"is too short for joint {joint!r}")
            obj = values[index]
        else:
            obj = getattr(obj, part)
    return obj


def first_nonfinite(msg: Any, prefix: str = "") -> tuple[str, float] | None:
    """The first non-finite float in ``msg`` (recursively, arrays included) as (field, value), else None."""
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        path = prefix + name
        if isinstance(value, float):
            if not math.isfinite(value):
                return path, value
        elif hasattr(value, "get_fields_and_field_types"):
            found = first_nonfinite(value, path + ".")
            if found is not None:
                return found
        elif isinstance(value, (np.ndarray, array.array)):
            numbers = np.asarray(value)
            if numbers.dtype.kind == "f" and not np.all(np.isfinite(numbers)):
                index = int(np.flatnonzero(~np.isfinite(numbers))[0])
                return f"{path}[{index}]", float(numbers[index])
        elif isinstance(value, (list, tuple)):
            for i, item in enumerate(value):
                if isinstance(item, float) and not math.isfinite(item):
                    return f"{path}[{i}]", item
                if hasattr(item, "get_fields_and_field_types"):
                    found = first_nonfinite(item, f"{path}[{i}].")
                    if found is not None:
                        return found
    return None


class _GravityWindow:
    """Running mean of the specific-force vector of one topic over a time window."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self.samples: deque[tuple[float, np.ndarray]] = deque()
        self.total: np.ndarray | None = None
        self.bad = False

    def add(self, t: float, vector: np.ndarray) -> None:
        self.samples.append((t, vector))
        self.total = vector.copy() if self.total is None else self.total + vector
        while self.samples and t - self.samples[0][0] > self.window_s:
            _, old = self.samples.popleft()
            self.total -= old

    def mean_norm(self) -> float | None:
        """|mean vector|, or None while the window spans less than half its length."""
        if self.total is None or len(self.samples) < 2:
            return None
        if self.samples[-1][0] - self.samples[0][0] < 0.5 * self.window_s:
            return None
        return float(np.linalg.norm(self.total / len(self.samples)))


class InputGuard:
    """Checks every input message of one estimator node (see the module docstring).

    Args:
        inputs: the adapter's input TopicSpecs (expected frame, fields, covariances,
            gravity fields).
        values: validated parameter values holding the ``input.*`` parameters.
    """

    def __init__(self, inputs: Sequence[Any], values: Mapping[str, ParamValue]) -> None:
        self.inputs = {spec.key: spec for spec in inputs}
        self.max_future_s = float(values["input.max_future_stamp"])
        self.gravity_tolerance = float(values["input.gravity_tolerance"])
        self.gravity_window_s = float(values["input.gravity_window"])
        self.rebase_after = int(values["input.restart_after_out_of_order"])
        self.rejected: dict[str, int] = {}
        self.accepted = 0
        self.reset()

    def reset(self) -> None:
        """Forget stamps and accelerometer windows (a clock jump); counters are kept."""
        self._last_stamp_ns: dict[str, int] = {}
        self._behind: dict[str, tuple[int, int]] = {}  # key -> (consecutive increasing out-of-order, last stamp)
        self._gravity = {
            key: _GravityWindow(self.gravity_window_s)
            for key, spec in self.inputs.items()
            if spec.gravity_fields and self.gravity_window_s > 0.0
        }

    def check(self, key: str, msg: Any, now_s: float | None) -> Rejection | None:
        """None when ``msg`` may reach the adapter, else why not (counted).

        Args:
            now_s: the node's clock (s), None when it does not run yet.
        """
        rejection = self._check(key, msg, now_s)
        if rejection is None:
            self.accepted += 1
        else:
            self.rejected[rejection.reason] = self.rejected.get(rejection.reason, 0) + 1
        return rejection

    def _check(self, key: str, msg: Any, now_s: float | None) -> Rejection | None:
        spec = self.inputs[key]
        topic = spec.topic
        if spec.frame_id and msg.header.frame_id != spec.frame_id:
            return Rejection(topic, "header.frame_id", repr(msg.header.frame_id), f"is not {spec.frame_id!r}")
        stamp_ns = stamp_to_ns(msg.header.stamp)
        stamp_s = stamp_ns * 1e-9
        if now_s is not None and stamp_s > now_s + self.max_future_s:
            return Rejection(
                topic,
                "header.stamp",
                f"{stamp_s:.9g} s (clock {now_s:.9g} s)",
                f"is more than input.max_future_stamp = {self.max_future_s:g} s ahead of the clock",
            )
        previous = self._last_stamp_ns.get(key)
        if previous is not None and stamp_ns == previous:
            return Rejection(topic, "header.stamp", f"{stamp_s:.9g} s", "duplicates the previous sample's")
        if previous is not None and stamp_ns < previous:
            count, last = self._behind.get(key, (0, -1))
            count = count + 1 if stamp_ns > last else 1
            self._behind[key] = (count, stamp_ns)
            value = f"{stamp_s:.9g} s (previous {previous * 1e-9:.9g} s)"
            if self.rebase_after > 0 and count >= self.rebase_after:
                self.reset()
                self._last_stamp_ns[key] = stamp_ns
                return Rejection(topic, "header.stamp", value, "went back for good (a new time line)", rebase=True)
            return Rejection(topic, "header.stamp", value, "is before the previous sample's (out of order)")
        self._behind.pop(key, None)
        for path in (*spec.fields, *spec.gravity_fields):
            try:
                value = field_value(msg, path)
            except LookupError as exc:
                return Rejection(topic, *exc.args)
            if not math.isfinite(float(value)):
                return Rejection(topic, path, _fmt(float(value)), "is not finite")
        for path in spec.covariances:
            problem = _covariance_problem(np.asarray(field_value(msg, path), dtype=float))
            if problem is not None:
                return Rejection(topic, path, problem[0], problem[1])
        window = self._gravity.get(key)
        if window is not None:
            rejection = self._check_gravity(spec, window, stamp_s, msg)
            if rejection is not None:
                self._last_stamp_ns[key] = stamp_ns  # the stream's order is still followed
                return rejection
        self._last_stamp_ns[key] = stamp_ns
        return None

    def _check_gravity(self, spec: Any, window: _GravityWindow, t: float, msg: Any) -> Rejection | None:
        window.add(t, np.array([float(field_value(msg, p)) for p in spec.gravity_fields]))
        norm = window.mean_norm()
        if norm is None:
            return None
        g = float(spec.gravity)
        tol = self.gravity_tolerance
        if abs(norm - g) <= tol * g:
            window.bad = False
            return None
        if abs(norm - g / STANDARD_GRAVITY) <= tol * g / STANDARD_GRAVITY:
            problem = "is in g, not m/s^2"
        elif norm < g:
            problem = "lacks gravity (REP 145: specific force, gravity included)"
        else:
            problem = "is not a specific force in m/s^2"
        fields = ", ".join(p.rsplit(".", 1)[-1] for p in spec.gravity_fields)
        prefix = spec.gravity_fields[0].rsplit(".", 1)[0]
        first = not window.bad
        window.bad = True
        return Rejection(
            spec.topic,
            f"{prefix} ({fields})",
            f"mean |a| {norm:.4g} m/s^2 over {self.gravity_window_s:g} s, expected {g:.4g} +- {100 * tol:g} %",
            problem,
            restart=first,
        )


def _covariance_problem(cov: np.ndarray) -> tuple[str, str] | None:
    """(value, problem) when a 3x3 row-major covariance is unusable, else None."""
    if cov.size != 9:
        return None
    if cov[0] == -1.0:
        return None  # not measured (sensor_msgs)
    if not np.all(np.isfinite(cov)):
        return _fmt_cov(cov), "is not finite"
    m = cov.reshape(3, 3)
    scale = float(np.max(np.abs(m)))
    if scale == 0.0:
        return None  # unknown (sensor_msgs)
    if float(np.max(np.abs(m - m.T))) > _COVARIANCE_TOLERANCE * scale:
        return _fmt_cov(cov), "is not symmetric"
    smallest = float(np.linalg.eigvalsh(m)[0])
    if smallest < -_COVARIANCE_TOLERANCE * scale:
        return f"{_fmt_cov(cov)} (eigenvalue {smallest:.3g})", "is not positive semi-definite"
    return None


def _fmt_cov(cov: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.3g}" for v in cov) + "]"
