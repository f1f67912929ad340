"""What ``terrain-estimate`` compares with a simulator's ground truth (``ground_truth/<topic>``).

Each estimate is compared with the latest truth message stamped at or before it (the truth is piecewise
constant between its samples): the RMS, final absolute and final relative error of every compared field.

* :func:`truth_errors`: from the estimates and the truth in memory (the reference);
* :func:`streamed_truth_errors`: the estimates of a run in memory, the truth read in one streaming pass, the
  same figures to the bit;
* :class:`TruthTally`: neither held: estimates and truth given one by one as a streamed run meets them in the
  bag's recorded order (:mod:`terrain_estimation.tools.estimate_stream`); the errors are running sums.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["HISTORY", "TruthTally", "numeric_fields", "stamp_s", "streamed_truth_errors", "truth_errors"]


def numeric_fields(msg: Any, prefix: str = "") -> dict[str, float]:
    """Flat ``{field path: value}`` of the numeric scalar fields of a message.

    Nested messages give ``outer.inner`` paths and arrays of messages
    ``wheels[0].slip`` (the rover's ``WheelTerrainArray``); numeric arrays
    and the header are left out.
    """
    out: dict[str, float] = {}
    for name in getattr(msg, "get_fields_and_field_types", dict)().keys():
        value = getattr(msg, name)
        path = f"{prefix}{name}"
        if isinstance(value, bool):
            continue
        if isinstance(value, (int, float)):
            out[path] = float(value)
        elif hasattr(value, "get_fields_and_field_types") and name != "header":
            out.update(numeric_fields(value, f"{path}."))
        elif isinstance(value, (list, tuple)):
            for i, item in enumerate(value):
                if hasattr(item, "get_fields_and_field_types"):
                    out.update(numeric_fields(item, f"{path}[{i}]."))
    return out


def stamp_s(msg: Any) -> float:
    """``msg.header.stamp`` in seconds."""
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def _error_figures(
    errors: Mapping[str, list[float]], last_ref: Mapping[str, float]
) -> dict[str, tuple[float, float, float]]:
    """RMS, final absolute and final relative error per field, from the errors in the estimates' order."""
    return {
        name: (
            math.sqrt(float(np.mean(np.square(e)))),
            abs(e[-1]),
            abs(e[-1]) / abs(last_ref[name]) if last_ref[name] else math.inf,
        )
        for name, e in errors.items()
        if e
    }


def truth_errors(
    estimates: Sequence[Any], truths: Sequence[Any], fields: Sequence[str]
) -> dict[str, tuple[float, float, float]]:
    """RMS, final absolute and final relative error of ``fields`` against ground truth.

    Each estimate is compared with the latest truth message stamped at or
    before it (truth is piecewise constant between its samples).
    """
    if not estimates or not truths:
        return {}
    t_truth = np.array([stamp_s(m) for m in truths])
    truth_fields = [numeric_fields(m) for m in truths]
    errors: dict[str, list[float]] = {}
    last_ref: dict[str, float] = {}
    for est in estimates:
        i = int(np.searchsorted(t_truth, stamp_s(est), side="right")) - 1
        if i < 0:
            continue
        ref = truth_fields[i]
        values = numeric_fields(est)
        for name in fields:
            errors.setdefault(name, []).append(values[name] - ref[name])
        last_ref = ref
    return _error_figures(errors, last_ref)


def streamed_truth_errors(run: Any) -> dict[str, dict[str, tuple[float, float, float]]]:
    """:func:`truth_errors` of every estimate topic of ``run`` (an
    :class:`~terrain_estimation.tools.estimate.EstimationRun` that kept its outputs), reading the ground truth
    in one streaming pass.

    The truth is never held whole (an hour of a 100 Hz truth topic is a few hundred MB of messages): each
    estimate gets the compared fields of the latest truth message stamped at or before it while the truth
    goes by in recorded order (stamps ascending, as :func:`truth_errors`' search assumes), and the errors
    are then formed in the estimates' order, so the figures are :func:`truth_errors`' to the bit. A truth
    already in memory (``run.truth`` read, or decoded during the run) is used as it is.
    """
    topics = sorted({t for t, _, _ in run.outputs})
    fields = {t: tuple(run.truth_fields.get(t, ())) for t in topics}
    stamps = {t: np.array([stamp_s(m) for m in run.messages(t)]) for t in topics}
    order = {t: np.argsort(stamps[t], kind="stable") for t in topics}
    refs: dict[str, list[dict[str, float] | None]] = {t: [None] * len(stamps[t]) for t in topics}
    cursor = dict.fromkeys(topics, 0)
    current: dict[str, dict[str, float] | None] = dict.fromkeys(topics)
    if "_truth" in run.__dict__ or run.truth_reader is None:
        items: Iterable[tuple[str, Any]] = ((t, m) for t, ms in run.truth.items() for m in ms)
    else:
        items = run.truth_reader()
    for topic, msg in items:
        if topic not in refs:
            continue
        s, k, idx = stamp_s(msg), cursor[topic], order[topic]
        t_est, ref = stamps[topic], refs[topic]
        while k < idx.size and t_est[idx[k]] < s:  # these estimates lie before this truth message
            ref[idx[k]] = current[topic]
            k += 1
        cursor[topic] = k
        values = numeric_fields(msg)
        current[topic] = {name: values[name] for name in fields[topic]}
    out: dict[str, dict[str, tuple[float, float, float]]] = {}
    for topic in topics:
        idx, ref = order[topic], refs[topic]
        for k in range(cursor[topic], idx.size):
            ref[idx[k]] = current[topic]
        errors: dict[str, list[float]] = {}
        last_ref: dict[str, float] = {}
        for est, r in zip(run.messages(topic), ref, strict=True):
            if r is None:
                continue
            values = numeric_fields(est)
            for name in fields[topic]:
                errors.setdefault(name, []).append(values[name] - r[name])
            last_ref = r
        out[topic] = _error_figures(errors, last_ref)
    return out


HISTORY = 256
"""Truth messages a :class:`TruthTally` keeps the reference of (at least; twice at most) for estimates that
arrive after later truth. In the shipped and the simulated bags an estimate looks back at most 5 truth
messages (the rover's, made from a window of its inputs); each kept reference is a tuple of the compared
fields (about 0.4 kB for the rover's 12), so a longer history costs memory that no bag needs."""


class TruthTally:
    """:func:`truth_errors` of one estimate topic with neither the estimates nor the truth held.

    Give it every estimate of the topic (:meth:`estimate`) and every ground-truth message (:meth:`truth`)
    in the bag's recorded order, then :meth:`figures`. The rule is :func:`streamed_truth_errors`', to the
    pairing: an estimate stamped ``t`` is compared with the truth message read just before the first truth
    message stamped after ``t`` (the last one when none is; none when that is the first). An estimate
    stamped at or after every truth read so far waits for that message (in ``pending``: the estimates
    between two truth samples); one stamped before a truth already read finds it among the references
    where the truth's stamps rose (the last :data:`HISTORY` of them). The squared errors are summed exactly
    rounded (Shewchuk's partials, as :func:`math.fsum`); :func:`truth_errors` sums them pairwise
    (``np.mean``), so the RMS may differ from it in the last bit (the figures are printed to 6 digits).

    Memory does not grow with the bag, except in ``pending`` when the truth stops before the estimates do
    (an estimate then waits to the end of the bag).
    """

    def __init__(self, fields: Sequence[str]) -> None:
        self.fields = tuple(fields)
        self.top = -math.inf  # the largest truth stamp read so far
        self.current: tuple[float, ...] | None = None  # compared fields of the last truth message read
        self.rises: list[float] = []  # truth stamps that raised ``top``, ascending ...
        self.refs: list[tuple[float, ...] | None] = []  # ... and the truth read just before each
        self.forgotten = False  # ``rises`` lost its oldest entries (beyond HISTORY)
        self.pending: list[tuple[float, int, tuple[float, ...]]] = []  # (stamp, index, compared fields)
        self.index = 0  # estimates given so far (their order in the run's outputs)
        self.compared = 0  # estimates with a truth to compare with
        self.beyond_history = 0  # estimates whose truth was forgotten (compared with the oldest kept)
        self._partials: list[list[float]] = [[] for _ in self.fields]
        self._plain = [0.0] * len(self.fields)  # the same sums, plainly: non-finite when they are
        self._last: tuple[int, tuple[float, ...], tuple[float, ...]] | None = None  # index, errors, truth

    def estimate(self, msg: Any) -> None:
        """The next estimate of the topic (in output order)."""
        values = numeric_fields(msg)
        compared = tuple(values[name] for name in self.fields)
        t, index = stamp_s(msg), self.index
        self.index += 1
        if t >= self.top:  # the truth message that decides has not been read yet
            self.pending.append((t, index, compared))
            return
        k = bisect.bisect_right(self.rises, t)  # the first truth read that is stamped after it
        if k == 0 and self.forgotten:
            self.beyond_history += 1
        self._add(index, compared, self.refs[k])

    def truth(self, msg: Any) -> None:
        """The next ground-truth message of the topic (in recorded order)."""
        s = stamp_s(msg)
        if s > self.top:
            if self.pending:  # the estimates stamped before it are compared with the truth read before it
                waiting = self.pending
                self.pending = [p for p in waiting if p[0] >= s]
                for t, index, compared in waiting:
                    if t < s:
                        self._add(index, compared, self.current)
            self.top = s
            self.rises.append(s)
            self.refs.append(self.current)
            if len(self.rises) > 2 * HISTORY:
                del self.rises[:HISTORY], self.refs[:HISTORY]
                self.forgotten = True
        values = numeric_fields(msg)
        self.current = tuple(values[name] for name in self.fields)

    def figures(self) -> dict[str, tuple[float, float, float]]:
        """RMS, final absolute and final relative error per field (the bag read to its end)."""
        waiting, self.pending = self.pending, []
        for _t, index, compared in waiting:
            self._add(index, compared, self.current)
        if self._last is None:
            return {}
        _, errors, ref = self._last
        out = {}
        for i, name in enumerate(self.fields):
            total = self._plain[i] if not math.isfinite(self._plain[i]) else math.fsum(self._partials[i])
            e = errors[i]
            out[name] = (math.sqrt(total / self.compared), abs(e), abs(e) / abs(ref[i]) if ref[i] else math.inf)
        return out

    def _add(self, index: int, compared: tuple[float, ...], ref: tuple[float, ...] | None) -> None:
        if ref is None:
            return
        errors = tuple(v - r for v, r in zip(compared, ref, strict=True))
        self.compared += 1
        for i, e in enumerate(errors):
            square = e * e
            self._plain[i] += square
            _add_exact(self._partials[i], square)
        if self._last is None or index > self._last[0]:
            self._last = (index, errors, ref)


def _add_exact(partials: list[float], x: float) -> None:
    """Add ``x`` to the exact sum held as non-overlapping ``partials`` (Shewchuk; :func:`math.fsum` rounds them)."""
    if not math.isfinite(x):
        return  # the plain sum carries it
    i = 0
    for y in partials:
        if abs(x) < abs(y):
            x, y = y, x
        hi = x + y
        lo = y - (hi - x)
        if lo:
            partials[i] = lo
            i += 1
        x = hi
    partials[i:] = [x]
