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
* fields with a physical range (``TopicSpec.bounds``, e.g. a load cell's
  force): a sample beyond it is a glitch and is rejected alone;
* covariance arrays (3x3, row major) are finite, symmetric and positive
  semi-definite, unless marked not measured (first element -1, the
  sensor_msgs convention);
* accelerometers, each sample: no specific-force component (``gravity_fields``)
  beyond ``input.max_acceleration`` (in standard g). No vehicle accelerometer
  reads that much (MEMS parts saturate at 2-16 g, a hard impact is tens of g):
  such a sample is a glitch and is rejected alone, before it enters the
  window below, so it costs that one sample;
* accelerometers, over the last ``input.gravity_window`` seconds: the
  magnitude of the mean specific force is within ``input.gravity_tolerance``
  of the vehicle's gravity (REP 145: specific force, gravity included, in
  m/s²), and, when ``z`` is among the gravity fields, it points up (REP 103:
  z up, a vehicle at rest reads +g on z): its z component is positive and it
  is tilted from +z by at most ``input.gravity_max_tilt`` (a slope tilts
  gravity in the body frame; the rover's x-z fields see the pitch only).
  Without a z field the direction is not checked. A stream in g (mean ≈ 1),
  with gravity removed (mean ≈ 0), upside down or on its side is rejected
  until it is plausible again. The mean needs half a window of samples to be
  judged (again after a gap that emptied the window); the samples taken
  before the verdict (or those of a stream that drifts out of the band) may
  have reached the filter, so the first rejection of this kind asks the node
  to restart the estimator (:attr:`Rejection.restart`), and until every
  accelerometer has been judged plausible (:attr:`InputGuard.gravity_judged`)
  no estimate may claim to have converged.

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
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from operator import attrgetter
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
    return _path_getter(path)(msg)


@lru_cache(maxsize=1024)
def _path_getter(path: str) -> Callable[[Any], Any]:
    """``path`` parsed once: a function of the message doing :func:`field_value`."""
    if "[" not in path:
        return attrgetter(path)
    steps: list[tuple[str, str | None]] = []
    for part in path.split("."):
        if part.endswith("]") and "[" in part:
            attr, joint = part[:-1].split("[", 1)
            steps.append((attr, joint))
        else:
            steps.append((part, None))

    def get(msg: Any) -> Any:
        obj = msg
        for attr, joint in steps:
            if joint is None:
                obj = getattr(obj, attr)
                continue
            values = getattr(obj, attr)
            names = list(obj.name)
            if joint not in names:
                raise LookupError("name", repr(names)[:200], f"lacks joint {joint!r} (for {attr})")
            index = names.index(joint)
            if index >= len(values):
                raise LookupError(f"len({attr})", str(len(values)), f"is too short for joint {joint!r}")
            obj = values[index]
        return obj

    return get


def first_nonfinite(msg: Any, prefix: str = "") -> tuple[str, float] | None:
    """The first non-finite float in ``msg`` (recursively, arrays included) as (field, value), else None."""
    if _all_finite(msg):
        return None
    return _first_nonfinite_walk(msg, prefix)


def _first_nonfinite_walk(msg: Any, prefix: str = "") -> tuple[str, float] | None:
    """:func:`first_nonfinite` field by field: the reference, run when :func:`_all_finite` is not sure."""
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        path = prefix + name
        if isinstance(value, float):
            if not math.isfinite(value):
                return path, value
        elif hasattr(value, "get_fields_and_field_types"):
            found = _first_nonfinite_walk(value, path + ".")
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
                    found = _first_nonfinite_walk(item, f"{path}[{i}].")
                    if found is not None:
                        return found
    return None


# -- the fast path of first_nonfinite ---------------------------------------------------------
#
# Per message class, a plan made once from the first message seen: the nested messages
# (expanded into dotted paths, their classes checked on every call), the numeric scalar
# fields (summed: a finite sum proves every term finite) and the other fields (checked
# by their run-time type, as _first_nonfinite_walk does). True proves that the walk
# would find nothing; False (a non-finite value, an overflowing sum, anything
# unexpected) hands the message to the walk, which finds the first non-finite float.


def _tuple_getter(paths: Sequence[str]) -> Callable[[Any], tuple[Any, ...]]:
    """attrgetter of ``paths`` that always returns a tuple."""
    if not paths:
        return lambda _msg: ()
    if len(paths) == 1:
        get = attrgetter(paths[0])
        return lambda msg: (get(msg),)
    return attrgetter(*paths)


@dataclass(frozen=True)
class _Plan:
    nested: Callable[[Any], tuple[Any, ...]]  # the nested messages
    types: tuple[type, ...]  # ... and their classes
    scalars: Callable[[Any], tuple[Any, ...]]  # int, float and bool fields
    others: Callable[[Any], tuple[Any, ...]]  # strings, arrays, sequences, anything else
    check: Callable[[Any], bool] | None = None  # the same test as one generated function (_compile_plan)


_PLANS: dict[type, _Plan | None] = {}


def _compile_plan(nested: Sequence[str], types: Sequence[type], scalars: Sequence[str], others: Sequence[str]) -> Any:
    """The plan's test as one function: each nested message read once into a local (its class checked),
    the scalars summed from the locals, the other fields through :func:`_value_finite`. The same verdict as
    the attrgetter form (a sum is finite exactly when every term is, barring an overflow, which both hand
    to the walk), without resolving every dotted path from the top. None for a path it cannot name."""
    names: dict[str, str] = {"": "m"}
    lines = ["def check(m):"]
    env: dict[str, Any] = {"_isfinite": math.isfinite, "_value_finite": _value_finite, "_str": str}

    def local(path: str) -> str:
        head, _, attr = path.rpartition(".")
        if not attr.isidentifier() or head not in names:
            raise ValueError(path)
        return f"{names[head]}.{attr}"

    try:
        for i, (path, cls) in enumerate(zip(nested, types, strict=True)):
            var = f"n{i}"
            env[f"T{i}"] = cls
            lines.append(f"    {var} = {local(path)}")
            lines.append(f"    if type({var}) is not T{i}: return False")
            names[path] = var
        lines.append(f"    if not _isfinite(0 + {' + '.join(local(p) for p in scalars) or '0'}): return False")
        for path in others:
            lines.append(f"    v = {local(path)}")
            lines.append("    if type(v) is not _str and not _value_finite(v): return False")
    except ValueError:
        return None
    lines.append("    return True")
    exec(compile("\n".join(lines) + "\n", "<finite check>", "exec"), env)
    return env["check"]


def _storage(cls: type, name: str, obj: Any) -> str:
    """Where field ``name`` is stored: the rosidl slot ``_name`` behind the property ``name``, else ``name``."""
    slot = "_" + name
    if isinstance(getattr(cls, name, None), property) and slot in getattr(cls, "__slots__", ()):
        try:
            if getattr(obj, slot) is getattr(obj, name):
                return slot
        except AttributeError:
            pass
    return name


def _make_plan(msg: Any) -> _Plan | None:
    nested: list[str] = []
    types: list[type] = []
    scalars: list[str] = []
    others: list[str] = []

    def walk(obj: Any, prefix: str) -> None:
        for name in obj.get_fields_and_field_types():
            attr = _storage(type(obj), name, obj)
            value = getattr(obj, attr)
            path = prefix + attr
            if isinstance(value, (int, float)):
                scalars.append(path)
            elif hasattr(value, "get_fields_and_field_types"):
                nested.append(path)
                types.append(type(value))
                walk(value, path + ".")
            else:
                others.append(path)

    try:
        walk(msg, "")
    except Exception:  # not a message this plan can describe: the walk decides
        return None
    check = _compile_plan(nested, types, scalars, others)
    return _Plan(_tuple_getter(nested), tuple(types), _tuple_getter(scalars), _tuple_getter(others), check)


def _all_finite(msg: Any) -> bool:
    """True when :func:`_first_nonfinite_walk` would find nothing in ``msg``; False: run it."""
    cls = type(msg)
    try:
        plan = _PLANS[cls]
    except KeyError:
        plan = _PLANS[cls] = _make_plan(msg)
    if plan is None:
        return False
    try:
        if plan.check is not None:
            return plan.check(msg)
        if plan.types and tuple(map(type, plan.nested(msg))) != plan.types:
            return False
        if not math.isfinite(sum(plan.scalars(msg))):
            return False
        for value in plan.others(msg):
            if type(value) is not str and not _value_finite(value):
                return False
    except Exception:  # anything unexpected: the walk decides (and raises if it does)
        return False
    return True


_INT_TYPECODES = frozenset("bBhHiIlLqQ")


def _value_finite(value: Any) -> bool:
    """False when ``value`` (a field that is not a numeric scalar) may hold a non-finite float."""
    if isinstance(value, float):
        return math.isfinite(value)
    if hasattr(value, "get_fields_and_field_types"):
        return _all_finite(value)
    if isinstance(value, np.ndarray):
        if value.dtype.kind != "f":
            return True
        if value.ndim == 1 and value.size <= 256:
            return math.isfinite(sum(value.tolist()))
        return bool(np.isfinite(value).all())
    if isinstance(value, array.array):
        if value.typecode in _INT_TYPECODES:
            return True
        return value.typecode in "fd" and math.isfinite(sum(value))
    if isinstance(value, (list, tuple)):
        for item in value:
            if isinstance(item, float):
                if not math.isfinite(item):
                    return False
            elif hasattr(item, "get_fields_and_field_types") and not _all_finite(item):
                return False
    return True


_EXACT_ABOVE = 1e3
"""[m/s^2] (≈ 100 g) a window sample with a component beyond this makes the window recompute its sum
exactly once the sample has left: a running sum keeps the rounding error of every value that passed
through it ((9.8 + 1e20) - 1e20 is 0); below this bound that error is some 1e-13 m/s^2 of the mean."""


class _GravityWindow:
    """Running mean of the specific-force vector of one topic over a time window.

    The sum runs in floats (Python floats: the same sums as float64 arrays, faster). A
    sample beyond :data:`_EXACT_ABOVE` (only let in with ``input.max_acceleration``
    raised, or driven directly) would leave its rounding error, or an infinity, in it
    for ever: once the newest such sample has left, the sum is recomputed exactly
    (:func:`math.fsum`) from the samples in the window.

    Attributes:
        verdict: None while not judged (less than half a window of samples), else
            whether the last judgement found the stream plausible (set by the guard).
    """

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self.half_s = 0.5 * window_s
        self.samples: deque[tuple[float, tuple[float, ...]]] = deque()
        self.total: list[float] | None = None
        self.verdict: bool | None = None
        self._pops_to_exact = 0  # pops until the newest sample beyond _EXACT_ABOVE has left (0: none inside)

    def add(self, t: float, vector: tuple[float, ...]) -> None:
        samples = self.samples
        samples.append((t, vector))
        if len(vector) == 1 and self.total is not None and not self._pops_to_exact:
            self._add_one(t, vector[0])  # the same sums, one field
            return
        if self.total is None:
            self.total = list(vector)
        else:
            self.total = [a + b for a, b in zip(self.total, vector, strict=True)]
        if not -_EXACT_ABOVE <= min(vector) <= max(vector) <= _EXACT_ABOVE:  # (NaN: never reaches the guard's)
            self._pops_to_exact = len(samples)
        while t - samples[0][0] > self.window_s:
            _, old = samples.popleft()
            self.total = [a - b for a, b in zip(self.total, old, strict=True)]
            if self._pops_to_exact:
                self._pops_to_exact -= 1
                if not self._pops_to_exact:
                    self.total = [math.fsum(column) for column in zip(*(v for _, v in samples), strict=True)]

    def _add_one(self, t: float, value: float) -> None:
        """:meth:`add` of a one-field sample (already appended) with no sample beyond :data:`_EXACT_ABOVE` in."""
        assert self.total is not None
        samples = self.samples
        total = self.total[0] + value
        if not -_EXACT_ABOVE <= value <= _EXACT_ABOVE:
            self._pops_to_exact = len(samples)
        window_s = self.window_s
        while t - samples[0][0] > window_s:
            total -= samples.popleft()[1][0]
            if self._pops_to_exact:
                self._pops_to_exact -= 1
                if not self._pops_to_exact:
                    total = math.fsum(v[0] for _, v in samples)
        self.total = [total]

    def mean(self) -> list[float] | None:
        """The mean vector, or None while the window spans less than half its length."""
        samples = self.samples
        if self.total is None or len(samples) < 2 or samples[-1][0] - samples[0][0] < self.half_s:
            return None
        n = len(samples)
        return [s / n for s in self.total]

    def mean_norm(self) -> float | None:
        """|mean vector|, or None while the window spans less than half its length."""
        return _norm(self.mean())


def _norm(mean: list[float] | None) -> float | None:
    """|mean| of :meth:`_GravityWindow.mean`, None for None."""
    if mean is None:
        return None
    if max(map(abs, mean)) > 1e150:  # |mean|² would overflow (fuzzed input): what it gave, unwarned
        return math.inf
    if len(mean) == 1:  # one field (the soil estimators' z): the dot product is the one product
        return math.sqrt(mean[0] * mean[0])
    vector = np.array(mean)
    return math.sqrt(float(vector.dot(vector)))  # what np.linalg.norm computes, without its overhead


class InputGuard:
    """Checks every input message of one estimator node (see the module docstring).

    Args:
        inputs: the adapter's input TopicSpecs (expected frame, fields, covariances,
            gravity fields).
        values: validated parameter values holding the ``input.*`` parameters.

    Attributes:
        gravity_judged: every accelerometer's window has been judged plausible and
            holds that verdict (True without accelerometer checks). While False, input
            that may later be found bad can reach the estimator: runners tell the
            adapter before each message (``inputs_judged``), and no estimate made
            meanwhile may claim to have converged.
    """

    def __init__(self, inputs: Sequence[Any], values: Mapping[str, ParamValue]) -> None:
        self.inputs = {spec.key: spec for spec in inputs}
        self.max_future_s = float(values["input.max_future_stamp"])
        self.gravity_tolerance = float(values["input.gravity_tolerance"])
        self.gravity_window_s = float(values["input.gravity_window"])
        self.max_acceleration_g = float(values["input.max_acceleration"])
        self.max_acceleration = self.max_acceleration_g * STANDARD_GRAVITY
        self.max_tilt_deg = float(values["input.gravity_max_tilt"])
        self.min_cos_tilt = math.cos(math.radians(self.max_tilt_deg))
        self.rebase_after = int(values["input.restart_after_out_of_order"])
        self.rejected: dict[str, int] = {}
        self.accepted = 0
        self._plans: dict[str, _InputPlan] = {}
        # (key, covariance field) -> the bytes of the last covariance found usable: a sensor
        # usually sends the same one every time, and the same bytes get the same verdict.
        self._usable_covariance: dict[tuple[str, str], bytes] = {}
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
        self.gravity_judged = not self._gravity

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
        rejection = self._check_order(key, topic, stamp_ns)
        if rejection is not None:
            return rejection
        plan = self._plan(key)
        values = []
        for (path, get), bound in zip(plan.fields, plan.bounds, strict=True):
            try:
                value = get(msg)
            except LookupError as exc:
                return Rejection(topic, *exc.args)
            if not math.isfinite(float(value)):
                return Rejection(topic, path, _fmt(float(value)), "is not finite")
            if bound is not None and not -bound[0] <= value <= bound[0]:
                self._last_stamp_ns[key] = stamp_ns  # the stream's order is still followed
                return Rejection(topic, path, _fmt(float(value)), f"is beyond {bound[0]:.4g} ({bound[1]}): a glitch")
            values.append(value)
        covariances = (np.asarray(get(msg), dtype=float) for _path, get in plan.covariances)
        return self._check_tail(key, spec, plan, stamp_ns, values, covariances)

    def _check_tail(
        self, key: str, spec: Any, plan: _InputPlan, stamp_ns: int, values: Sequence[Any], covariances: Iterable[Any]
    ) -> Rejection | None:
        """:meth:`check` after the fields: the covariances (``plan.covariances``' arrays, in order), then an
        accelerometer's specific force; the stamp becomes the topic's last."""
        for (path, _get), cov in zip(plan.covariances, covariances, strict=True):
            raw = cov.tobytes() if cov.ndim == 1 else None
            if raw is not None and self._usable_covariance.get((key, path)) == raw:
                continue
            problem = _covariance_problem(cov)
            if problem is not None:
                return Rejection(spec.topic, path, problem[0], problem[1])
            if raw is not None:
                self._usable_covariance[(key, path)] = raw
        if plan.gravity_fields:  # an accelerometer: its specific force
            vector = tuple(map(float, values[len(spec.fields) :]))
            rejection = self._check_specific_force(key, spec, plan, stamp_ns * 1e-9, vector)
            if rejection is not None:
                self._last_stamp_ns[key] = stamp_ns  # the stream's order is still followed
                return rejection
        self._last_stamp_ns[key] = stamp_ns
        return None

    def _check_order(self, key: str, topic: str, stamp_ns: int) -> Rejection | None:
        """The stamp against the previous accepted one of ``key``: a duplicate, out of order, or a new time line."""
        previous = self._last_stamp_ns.get(key)
        if previous is not None and stamp_ns <= previous:
            stamp_s = stamp_ns * 1e-9
            if stamp_ns == previous:
                return Rejection(topic, "header.stamp", f"{stamp_s:.9g} s", "duplicates the previous sample's")
            count, last = self._behind.get(key, (0, -1))
            count = count + 1 if stamp_ns > last else 1
            self._behind[key] = (count, stamp_ns)
            value = f"{stamp_s:.9g} s (previous {previous * 1e-9:.9g} s)"
            if self.rebase_after > 0 and count >= self.rebase_after:
                self.reset()
                self._last_stamp_ns[key] = stamp_ns
                return Rejection(topic, "header.stamp", value, "went back for good (a new time line)", rebase=True)
            return Rejection(topic, "header.stamp", value, "is before the previous sample's (out of order)")
        if self._behind:
            self._behind.pop(key, None)
        return None

    # -- the offline path's checks on arrays ------------------------------------------------------------------
    def array_fields(self, key: str) -> tuple[str, ...]:
        """The fields the offline path decodes in bulk for ``key``, in this order: the checked fields (the
        TopicSpec's ``fields`` then ``gravity_fields``), then the covariances. Empty: ``key``'s messages are
        checked one by one (no frame to check, which fixes the layout, or a field not reachable as a path)."""
        spec = self.inputs[key]
        plan = self._plan(key)
        paths = (*(p for p, _ in plan.fields), *(p for p, _ in plan.covariances))
        return paths if spec.frame_id and not any("[" in p for p in paths) else ()

    def stateless_ok(self, key: str, stamp_ns: np.ndarray, clock_ns: np.ndarray, values: np.ndarray) -> np.ndarray:
        """Per message of ``key`` (its frame known to match): True when :meth:`check` would pass it on every
        rule that needs no state (the stamp not ahead of the clock, the checked fields finite and within their
        bounds), with the same comparisons and the same float arithmetic as :meth:`check`, on arrays.

        Args:
            stamp_ns: the stamps (int64 ns); clock_ns: the clock at each message (int64 ns, the bag's log time);
            values: the checked fields (:meth:`array_fields` without the covariances), one row per message.
        """
        plan = self._plan(key)
        ok = ~(stamp_ns * 1e-9 > clock_ns * 1e-9 + self.max_future_s)
        ok &= np.isfinite(values).all(axis=1)
        for column, bound in enumerate(plan.bounds):
            if bound is not None:
                ok &= (-bound[0] <= values[:, column]) & (values[:, column] <= bound[0])
        return ok

    def check_decoded(
        self, key: str, stamp_ns: int, values: Sequence[float], covariances: Sequence[np.ndarray]
    ) -> Rejection | None:
        """:meth:`check` of a message of ``key`` given by the numbers :meth:`array_fields` names, once
        :meth:`stateless_ok` passed it: what is left to judge needs the guard's state (the stamp's order, the
        covariances seen, the accelerometer's window). Counted as :meth:`check` counts."""
        spec = self.inputs[key]
        rejection = self._check_order(key, spec.topic, stamp_ns)
        if rejection is None:
            plan = self._plan(key)
            if plan.covariances or plan.gravity_fields:
                rejection = self._check_tail(key, spec, plan, stamp_ns, values, covariances)
            else:  # what the tail does without covariances and accelerometer
                self._last_stamp_ns[key] = stamp_ns
        if rejection is None:
            self.accepted += 1
        else:
            self.rejected[rejection.reason] = self.rejected.get(rejection.reason, 0) + 1
        return rejection

    def order_only(self, key: str) -> bool:
        """Whether, once :meth:`stateless_ok` passed a message of ``key``, only its stamp's order is left to
        judge (no covariances, no accelerometer): :meth:`accept_run` may judge a run of them."""
        plan = self._plan(key)
        return not plan.covariances and not plan.gravity_fields

    def accept_run(self, key: str, stamps_ns: Sequence[int]) -> int:
        """:meth:`check_decoded` of consecutive messages of an :meth:`order_only` ``key`` (each passed by
        :meth:`stateless_ok`), as long as it accepts them: each stamp after the one before (the first after the
        key's last accepted). How many it accepted, counted as :meth:`check` counts; the first one it would
        not accept (if any) is left to :meth:`check_decoded`, which names the reason."""
        last = self._last_stamp_ns.get(key)
        taken = 0
        for stamp_ns in stamps_ns:
            if last is not None and stamp_ns <= last:
                break
            last = stamp_ns
            taken += 1
        if taken:
            self._last_stamp_ns[key] = stamps_ns[taken - 1]
            if self._behind:
                self._behind.pop(key, None)
            self.accepted += taken
        return taken

    def _plan(self, key: str) -> _InputPlan:
        spec = self.inputs[key]
        plan = self._plans.get(key)
        if plan is None or plan.spec is not spec:
            plan = self._plans[key] = _InputPlan(spec)
        return plan

    def _check_specific_force(
        self, key: str, spec: Any, plan: _InputPlan, t: float, vector: tuple[float, ...]
    ) -> Rejection | None:
        """The sample's bound, then (with a window) its window's mean: magnitude and direction."""
        limit = self.max_acceleration
        if not -limit <= min(vector) <= max(vector) <= limit:
            index = max(range(len(vector)), key=lambda i: abs(vector[i]))
            return Rejection(
                spec.topic,
                plan.gravity_fields[index],
                _fmt(vector[index]),
                f"is beyond input.max_acceleration = {self.max_acceleration_g:g} g: "
                "no vehicle accelerometer reads that (a glitch)",
            )
        window = self._gravity.get(key)
        if window is None:
            return None
        window.add(t, vector)
        mean = window.mean()
        if mean is None:
            if window.verdict is not None:  # a gap emptied the window: to be judged again
                self._set_verdict(window, None)
            return None
        norm = _norm(mean)
        assert norm is not None
        g = float(spec.gravity)
        tol = self.gravity_tolerance
        if abs(norm - g) <= tol * g:
            z = plan.z_index
            if z is None or mean[z] > self.min_cos_tilt * norm:
                if not window.verdict:
                    self._set_verdict(window, True)
                return None
            tilt = math.degrees(math.acos(max(-1.0, min(1.0, mean[z] / norm))))
            components = ", ".join(f"{m:.4g}" for m in mean)
            value = f"mean a ({components}) m/s^2 over {self.gravity_window_s:g} s: {tilt:.0f} deg from +z"
            if mean[z] <= 0.0:
                problem = "points down: IMU mounted upside down or z axis flipped (REP 103: z up)"
            else:
                problem = (
                    f"is tilted more than input.gravity_max_tilt = {self.max_tilt_deg:g} deg from +z: "
                    "IMU mounted on its side or axes swapped (REP 103: z up)"
                )
        else:
            value = f"mean |a| {norm:.4g} m/s^2 over {self.gravity_window_s:g} s, expected {g:.4g} +- {100 * tol:g} %"
            if abs(norm - g / STANDARD_GRAVITY) <= tol * g / STANDARD_GRAVITY:
                problem = "is in g, not m/s^2"
            elif norm < g:
                problem = "lacks gravity (REP 145: specific force, gravity included)"
            else:
                problem = "is not a specific force in m/s^2"
        first = window.verdict is not False
        if first:
            self._set_verdict(window, False)
        return Rejection(spec.topic, plan.gravity_label, value, problem, restart=first)

    def _set_verdict(self, window: _GravityWindow, verdict: bool | None) -> None:
        window.verdict = verdict
        self.gravity_judged = all(w.verdict for w in self._gravity.values())


class _InputPlan:
    """The checked fields of one input TopicSpec, their paths parsed once."""

    def __init__(self, spec: Any) -> None:
        self.spec = spec
        self.fields = tuple((p, _path_getter(p)) for p in (*spec.fields, *spec.gravity_fields))
        limits = {path: (float(limit), why) for path, limit, why in spec.bounds}
        unknown = sorted(set(limits) - set(spec.fields))
        if unknown:
            raise ValueError(f"TopicSpec {spec.key!r}: bounds on fields it does not check: {unknown}")
        self.bounds: tuple[tuple[float, str] | None, ...] = tuple(limits.get(p) for p, _ in self.fields)
        self.covariances = tuple((p, _path_getter(p)) for p in spec.covariances)
        self.gravity_fields: tuple[str, ...] = tuple(spec.gravity_fields)
        names = [p.rsplit(".", 1)[-1] for p in self.gravity_fields]
        self.z_index = names.index("z") if "z" in names else None  # REP 103: the up axis, when checked
        prefix = self.gravity_fields[0].rsplit(".", 1)[0] if self.gravity_fields else ""
        self.gravity_label = f"{prefix} ({', '.join(names)})"


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
