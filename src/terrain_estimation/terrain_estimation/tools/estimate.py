"""``terrain-estimate BAG --vehicle V -o OUT_BAG``: estimate from a recorded bag.

Runs the vehicle's adapter and filter over the bag's sensor topics with no
ROS graph, in the bag's recorded order (the order a live replay publishes
them), and writes the estimates to a new bag, atomically. The estimates are
identical to those of the live node fed the same messages: both go through
the same adapter (tested in ``test/test_live_offline.py``).

A summary goes to stdout: messages read and written, the last estimate, and,
when the bag carries ``ground_truth/<topic>`` for an estimate topic (a
simulator's bag), the error of every numeric field against it.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from terrain_estimation.bag import AtomicBagWriter, BagError, read_bag
from terrain_estimation.params import ParameterError
from terrain_estimation.ros.validation import InputGuard, first_nonfinite
from terrain_estimation.vehicles import VEHICLES, estimator_parameters, get_vehicle

__all__ = ["EstimationRun", "estimate_bag", "run_adapter", "main", "numeric_fields", "topic_name"]


def topic_name(namespace: str, relative: str) -> str:
    """Absolute topic of ``relative`` under ``namespace``."""
    if relative.startswith("/"):
        return relative
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{relative}"


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


@dataclass
class EstimationRun:
    """What an offline run produced (messages in output order)."""

    outputs: list[tuple[str, Any, int]] = field(default_factory=list)  # (topic, msg, log time ns)
    inputs_read: int = 0
    truth: dict[str, list[Any]] = field(default_factory=dict)  # estimate topic -> truth messages
    truth_fields: dict[str, tuple[str, ...]] = field(default_factory=dict)  # estimate topic -> compared fields
    rejected: dict[str, int] = field(default_factory=dict)  # input check reason -> messages dropped
    restarts: int = 0  # estimator restarts asked by the input checks
    outputs_dropped: dict[str, int] = field(default_factory=dict)  # non-finite estimates never written

    def messages(self, topic: str) -> list[Any]:
        return [m for t, m, _ in self.outputs if t == topic]


def run_adapter(
    adapter: Any,
    namespace: str,
    bag: str | Path,
    *,
    progress: bool = False,
    values: Mapping[str, Any] | None = None,
) -> EstimationRun:
    """Feed ``adapter`` every input message of ``bag``, in recorded order.

    With the node's parameter ``values`` the messages pass the same input checks
    as in the live node (:class:`~terrain_estimation.ros.validation.InputGuard`;
    the clock for the future-stamp check is the bag's log time), rejections are
    counted in ``run.rejected`` and a non-finite estimate is never kept, so that
    live and offline runs agree on bad input too.

    Raises:
        BagError: the bag is unreadable (the message says how much was read).
    """
    inputs = {topic_name(namespace, s.topic): s.key for s in adapter.inputs}
    outputs = {s.key: topic_name(namespace, s.topic) for s in adapter.outputs}
    truth_topics = {
        topic_name(namespace, "ground_truth/" + s.topic): topic_name(namespace, s.topic) for s in adapter.outputs
    }
    run = EstimationRun(truth_fields={outputs[s.key]: s.truth_fields for s in adapter.outputs})
    guard = InputGuard(adapter.inputs, values) if values is not None else None
    started = time.monotonic()
    last_report = started
    for item in read_bag(bag, list(inputs) + list(truth_topics)):
        if item.topic in truth_topics:
            run.truth.setdefault(truth_topics[item.topic], []).append(item.msg)
            continue
        run.inputs_read += 1
        key_in = inputs[item.topic]
        if guard is not None:
            rejection = guard.check(key_in, item.msg, item.log_time_ns * 1e-9)
            if rejection is not None:
                run.rejected[rejection.reason] = run.rejected.get(rejection.reason, 0) + 1
                if rejection.restart or rejection.rebase:
                    run.restarts += 1
                    adapter.reset()
                continue
        for key, out in adapter.handle(key_in, item.msg):
            bad = first_nonfinite(out)
            if bad is not None:
                reason = f"{outputs[key]}: {bad[0]} not finite"
                run.outputs_dropped[reason] = run.outputs_dropped.get(reason, 0) + 1
                continue
            run.outputs.append((outputs[key], out, item.log_time_ns))
        if progress and time.monotonic() - last_report > 2.0:
            last_report = time.monotonic()
            print(
                f"  ... {run.inputs_read} messages, {len(run.outputs)} estimates, {last_report - started:.0f} s",
                file=sys.stderr,
            )
    return run


def estimate_bag(
    bag: str | Path,
    vehicle: str,
    *,
    namespace: str | None = None,
    config: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    progress: bool = False,
) -> EstimationRun:
    """Run ``vehicle``'s estimator over ``bag`` (see :func:`run_adapter`)."""
    entry = get_vehicle(vehicle)
    ns = namespace if namespace is not None else entry.namespace
    values = estimator_parameters(entry, config, overrides)
    adapter = entry.make_adapter(values, ns)
    return run_adapter(adapter, ns, bag, progress=progress, values=values)


def _stamp(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def truth_errors(
    estimates: Sequence[Any], truths: Sequence[Any], fields: Sequence[str]
) -> dict[str, tuple[float, float, float]]:
    """RMS, final absolute and final relative error of ``fields`` against ground truth.

    Each estimate is compared with the latest truth message stamped at or
    before it (truth is piecewise constant between its samples).
    """
    if not estimates or not truths:
        return {}
    t_truth = np.array([_stamp(m) for m in truths])
    truth_fields = [numeric_fields(m) for m in truths]
    errors: dict[str, list[float]] = {}
    last_ref: dict[str, float] = {}
    for est in estimates:
        i = int(np.searchsorted(t_truth, _stamp(est), side="right")) - 1
        if i < 0:
            continue
        ref = truth_fields[i]
        values = numeric_fields(est)
        for name in fields:
            errors.setdefault(name, []).append(values[name] - ref[name])
        last_ref = ref
    return {
        name: (
            math.sqrt(float(np.mean(np.square(e)))),
            abs(e[-1]),
            abs(e[-1]) / abs(last_ref[name]) if last_ref[name] else math.inf,
        )
        for name, e in errors.items()
        if e
    }


def _summary_lines(run: EstimationRun) -> Iterator[str]:
    yield f"input messages read: {run.inputs_read}"
    for reason, count in sorted(run.rejected.items()):
        yield f"  rejected {count}: {reason}"
    if run.restarts:
        yield f"  estimator restarted {run.restarts} time(s) by the input checks"
    for reason, count in sorted(run.outputs_dropped.items()):
        yield f"  not written {count}: {reason}"
    topics = sorted({t for t, _, _ in run.outputs})
    for topic in topics:
        msgs = run.messages(topic)
        yield f"{topic}: {len(msgs)} estimates"
        last = numeric_fields(msgs[-1])
        shown = ", ".join(f"{k}={v:.6g}" for k, v in list(last.items())[:8])
        yield f"  last: {shown}"
        errs = truth_errors(msgs, run.truth.get(topic, []), run.truth_fields.get(topic, ()))
        for name, (rms, final, rel) in errs.items():
            # A relative error above 1000 % says the truth is near zero (a sideslip on a straight run), not more.
            pct = f"{100 * rel:.2f} %" if rel <= 10.0 else "truth near 0"
            yield f"  vs ground truth {name}: rms error {rms:.6g}, final error {final:.6g} ({pct})"


def _parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    import yaml

    out: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep:
            raise ParameterError(f"--param {item!r}: expected NAME=VALUE")
        out[name.strip()] = yaml.safe_load(text)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="terrain-estimate",
        description="Run a vehicle's estimator over a recorded rosbag2 bag and write the estimates to a new bag.",
    )
    parser.add_argument("bag", help="input bag directory (mcap or sqlite3)")
    parser.add_argument("--vehicle", required=True, choices=sorted(VEHICLES), help="vehicle model")
    parser.add_argument("-o", "--output", required=True, help="output bag directory (replaced atomically)")
    parser.add_argument("--namespace", help="namespace the bag was recorded under (default: the vehicle's)")
    parser.add_argument("--config", help="parameter file (default: config/<vehicle>.yaml)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="override a parameter")
    args = parser.parse_args(argv)
    try:
        overrides = _parse_overrides(args.param)
        print(f"estimating {args.bag} as {args.vehicle} ...", file=sys.stderr)
        run = estimate_bag(
            args.bag, args.vehicle, namespace=args.namespace, config=args.config, overrides=overrides, progress=True
        )
        with AtomicBagWriter(args.output) as writer:
            writer.write_all(run.outputs)
    except (BagError, ParameterError, ValueError) as exc:
        print(f"terrain-estimate: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("terrain-estimate: interrupted; no output bag written", file=sys.stderr)
        return 130
    for line in _summary_lines(run):
        print(line)
    print(f"wrote {len(run.outputs)} messages to {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
