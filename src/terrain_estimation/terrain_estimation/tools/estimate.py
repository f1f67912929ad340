"""``terrain-estimate BAG --vehicle V -o OUT_BAG``: estimate from a recorded bag.

Runs the vehicle's adapter and filter over the bag's sensor topics with no
ROS graph, in the bag's recorded order (the order a live replay publishes
them), and writes the estimates to a new bag, atomically. The estimates are
identical to those of the live node fed the same messages: both go through
the same adapter (tested in ``test/test_live_offline.py``).

A summary goes to stdout: messages read, rejected (by reason) and written, what
the vehicle's adapter says about the run (its ``summary_lines()``, if it has
one: e.g. the skid steer's wheel-speed lookup and measured rate), the last
estimate, and, when the bag carries ``ground_truth/<topic>`` for an estimate
topic (a simulator's bag), the error of every numeric field against it.

``--config`` may be a file that describes another model of the vehicle in its
``/**`` section (``vehicle.kind`` other than the estimator's, e.g.
``config/husky.yaml``: the 4-wheel Husky of the sim-to-real replay) and the
estimator's view in the estimator's own section: then, as rcl applies such a
file to the node, the names of ``/**`` the estimator declares are taken, the
others are left to the file's other readers, and the estimator's section
(checked strictly) goes over them (:func:`config_values`,
:mod:`terrain_estimation.config_sections`).

Exit status (``terrain_estimation.cli``): 0 estimates written; 2 the input
cannot be used — nothing is written: a missing or corrupt bag, a topic recorded
with another message type than the contract's, no input topic of the vehicle in
the bag (a wrong ``--namespace``), no estimate at all (every input rejected, or
a required topic missing), a bad parameter, an output path that exists (see
``--overwrite``); 3 an internal error.
"""

from __future__ import annotations

import argparse
import gc
import math
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from terrain_estimation.bag import AtomicBagWriter, bag_contents, msgtype_name, read_bag
from terrain_estimation.cli import EXIT_OK, InputError, run_cli
from terrain_estimation.config_sections import describes_another_kind, node_file_values
from terrain_estimation.outputs import check_output_path
from terrain_estimation.params import ParamValue, parse_override, resolve_parameters
from terrain_estimation.ros.validation import InputGuard
from terrain_estimation.tools.estimate_replay import Replay, replay_bulk, replay_messages
from terrain_estimation.vehicles import VEHICLES, estimator_parameters, get_vehicle

__all__ = [
    "EstimationRun",
    "add_output_arguments",
    "config_values",
    "estimate_bag",
    "run_adapter",
    "main",
    "numeric_fields",
    "parse_overrides",
    "topic_name",
]


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
    """What an offline run produced (messages in output order).

    ``truth`` (a simulator's ``ground_truth/<topic>`` messages, by estimate topic) is read from the bag
    on first access, not during the run: only a summary against ground truth needs it, and decoding it
    during the replay cost as much as decoding the inputs (undecodable truth messages are counted in
    ``rejected`` when it is read).
    """

    outputs: list[tuple[str, Any, int]] = field(default_factory=list)  # (topic, msg, log time ns)
    inputs_read: int = 0
    truth_loader: Callable[[EstimationRun], dict[str, list[Any]]] | None = field(default=None, repr=False)
    # (estimate topic, truth message) of the bag's ground truth in recorded order, read anew at each call
    truth_reader: Callable[[], Iterator[tuple[str, Any]]] | None = field(default=None, repr=False)
    truth_fields: dict[str, tuple[str, ...]] = field(default_factory=dict)  # estimate topic -> compared fields
    rejected: dict[str, int] = field(default_factory=dict)  # input check reason -> messages dropped
    accepted: int = 0  # input messages that passed the checks (or all read, without checks)
    expected_topics: dict[str, str] = field(default_factory=dict)  # absolute input topic -> pkg/msg/Name
    topics_read: dict[str, int] = field(default_factory=dict)  # absolute input topic -> messages read
    restarts: int = 0  # estimator restarts asked by the input checks
    divergences: int = 0  # filter divergences caught and restarted (the adapter's health counters)
    limit_resets: int = 0  # ... of which estimates beyond the vehicle's stated limits
    outputs_dropped: dict[str, int] = field(default_factory=dict)  # non-finite estimates never written
    notes: list[str] = field(default_factory=list)  # the adapter's own summary lines (summary_lines())

    def messages(self, topic: str) -> list[Any]:
        return [m for t, m, _ in self.outputs if t == topic]

    @property
    def truth(self) -> dict[str, list[Any]]:
        """Estimate topic -> its ground-truth messages (read from the bag on first access)."""
        loaded: dict[str, list[Any]] | None = self.__dict__.get("_truth")
        if loaded is None:
            loaded = self.truth_loader(self) if self.truth_loader is not None else {}
            self.__dict__["_truth"] = loaded
        return loaded

    @truth.setter
    def truth(self, value: dict[str, list[Any]]) -> None:
        self.__dict__["_truth"] = value


def run_adapter(
    adapter: Any,
    namespace: str,
    bag: str | Path,
    *,
    progress: bool = False,
    values: Mapping[str, Any] | None = None,
    previous: bool = False,
    bulk: bool = True,
) -> EstimationRun:
    """Feed ``adapter`` every input message of ``bag``, in recorded order.

    The ground-truth topics are read when ``run.truth`` is first asked for, and the garbage collector
    pauses during the replay (``previous``: the truth decoded during the run and the collector running,
    as the path before those did, for the benchmark's side-by-side figures). The adapter's numeric
    inputs are decoded and checked in bulk (:func:`~terrain_estimation.tools.estimate_replay.replay_bulk`;
    ``bulk=False`` or ``previous``: every message as an object, as before, with the same estimates).

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
    types = {topic_name(namespace, s.topic): msgtype_name(s.msg_type) for s in adapter.inputs}
    run = EstimationRun(
        truth_fields={outputs[s.key]: s.truth_fields for s in adapter.outputs}, expected_topics=dict(types)
    )
    for s in adapter.outputs:
        types[topic_name(namespace, "ground_truth/" + s.topic)] = msgtype_name(s.msg_type)
    guard = InputGuard(adapter.inputs, values) if values is not None else None

    def undecodable(topic: str, _log_time_ns: int, exc: BaseException) -> None:
        # as the live node does: the sample is dropped, counted, and the run goes on
        if topic in inputs:
            run.inputs_read += 1
            run.topics_read[topic] = run.topics_read.get(topic, 0) + 1
        reason = f"{topic}: bytes do not decode as {types.get(topic, 'its type')}"
        run.rejected[reason] = run.rejected.get(reason, 0) + 1

    def read_truth() -> Iterator[tuple[str, Any]]:
        for item in read_bag(bag, list(truth_topics), types=types, on_undecodable=undecodable):
            yield truth_topics[item.topic], item.msg

    def load_truth(run: EstimationRun) -> dict[str, list[Any]]:
        truth: dict[str, list[Any]] = {}
        for topic, msg in read_truth():
            truth.setdefault(topic, []).append(msg)
        return truth

    run.truth_loader, run.truth_reader = load_truth, read_truth
    # Every topic's type is checked (``types`` holds the truth topics too) before any message is read.
    # ``previous``: the truth decoded in the same pass, as the previous path did (benchmarks).
    read = list(inputs) + (list(truth_topics) if previous else [])
    eager: dict[str, list[Any]] = {}
    # The cyclic garbage collector is paused for the replay (not on the previous path): the run keeps every
    # output message, and the collector's full passes traverse them again and again (a fifth of the CPU of
    # a 60 s skid-steer replay). The replay's objects (messages, estimates) hold no reference cycles;
    # whatever cycles it makes (an exception's traceback) are collected when the collector resumes.
    collecting = gc.isenabled()
    if not previous:
        gc.disable()
    try:
        replay = Replay(run, adapter, bag, read, types, undecodable, inputs, outputs, guard, progress)
        if previous or not bulk:
            replay_messages(replay, truth_topics, eager)
        else:
            replay_bulk(replay)
    finally:
        if collecting:
            gc.enable()
    if previous:
        run.truth = eager
    return run


def estimate_bag(
    bag: str | Path,
    vehicle: str,
    *,
    namespace: str | None = None,
    config: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    progress: bool = False,
    reference: bool = False,
    bulk: bool = True,
) -> EstimationRun:
    """Run ``vehicle``'s estimator over ``bag`` (see :func:`run_adapter`).

    Args:
        reference: the previous path, for benchmarks and tests that compare the two: the reference
            (Python) filter step where an adapter also has a compiled one (``adapter.set_compiled(False)``:
            the skid steer's), the ground truth decoded during the run, the garbage collector running
            (:func:`run_adapter`). The estimates agree to rounding.
        bulk: the numeric inputs decoded and checked in bulk (the default; False: one message at a time, as
            before; the same estimates, bit for bit: :func:`run_adapter`).
    """
    entry = get_vehicle(vehicle)
    ns = namespace if namespace is not None else entry.namespace
    values = config_values(entry, config, overrides)
    adapter = entry.make_adapter(values, ns)
    set_compiled = getattr(adapter, "set_compiled", None)
    if reference and callable(set_compiled):
        set_compiled(False)
    run = run_adapter(adapter, ns, bag, progress=progress, values=values, previous=reference, bulk=bulk)
    health = getattr(getattr(adapter, "health", None), "values", {})
    run.divergences = int(health.get("divergences", 0))
    run.limit_resets = int(health.get("limit_resets", 0))
    summary = getattr(adapter, "summary_lines", None)
    run.notes = list(summary()) if callable(summary) else []
    return run


def config_values(
    entry: Any, config: str | Path | None = None, overrides: Mapping[str, Any] | None = None
) -> dict[str, ParamValue]:
    """The estimator's parameters: specs' defaults < ``config`` (default ``config/<vehicle>.yaml``) < ``overrides``.

    :func:`~terrain_estimation.vehicles.estimator_parameters`, except that a file whose ``/**`` section
    describes another vehicle kind (``config/husky.yaml``) is read as rcl applies it to the node
    (:func:`~terrain_estimation.config_sections.node_file_values`).

    Raises:
        ParameterError: an unknown name or invalid value (in the estimator's section, or in ``overrides``).
    """
    # One parse per process for the same file (path, size and modification time) and overrides: a batch of
    # bags, or a benchmark, runs many bags with one configuration (the YAML parse costs about 20 ms).
    file = Path(config) if config is not None else entry.config_path()
    try:
        st = file.stat()
        stamp: tuple[int, int] | None = (st.st_mtime_ns, st.st_size)
    except OSError:
        stamp = None
    key = (entry.name, str(config), stamp, repr(sorted((overrides or {}).items())))
    cached = _CONFIG_CACHE.get(key)
    if cached is None:
        cached = _config_values(entry, config, overrides)
        if len(_CONFIG_CACHE) > 64:
            _CONFIG_CACHE.clear()
        _CONFIG_CACHE[key] = cached
    return {k: list(v) if isinstance(v, list) else v for k, v in cached.items()}


_CONFIG_CACHE: dict[tuple[Any, ...], dict[str, ParamValue]] = {}


def _config_values(
    entry: Any, config: str | Path | None = None, overrides: Mapping[str, Any] | None = None
) -> dict[str, ParamValue]:
    """:func:`config_values` without its cache."""
    from terrain_estimation.ros.framework import EstimatorNode

    specs = tuple(EstimatorNode.COMMON_SPECS) + tuple(entry.specs)
    path = Path(config) if config is not None else None
    if path is None or not path.exists() or not describes_another_kind(path, entry.node_name, specs):
        return estimator_parameters(entry, config, overrides)
    values = node_file_values(path, entry.node_name, specs)
    return resolve_parameters(specs, {**values, **(overrides or {})}, strict=True, source="--param")


def _stamp(msg: Any) -> float:
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
    return _error_figures(errors, last_ref)


def streamed_truth_errors(run: EstimationRun) -> dict[str, dict[str, tuple[float, float, float]]]:
    """:func:`truth_errors` of every estimate topic of ``run``, reading the ground truth in one streaming pass.

    The truth is never held whole (an hour of a 100 Hz truth topic is a few hundred MB of messages): each
    estimate gets the compared fields of the latest truth message stamped at or before it while the truth
    goes by in recorded order (stamps ascending, as :func:`truth_errors`' search assumes), and the errors
    are then formed in the estimates' order, so the figures are :func:`truth_errors`' to the bit. A truth
    already in memory (``run.truth`` read, or decoded during the run) is used as it is.
    """
    topics = sorted({t for t, _, _ in run.outputs})
    fields = {t: tuple(run.truth_fields.get(t, ())) for t in topics}
    stamps = {t: np.array([_stamp(m) for m in run.messages(t)]) for t in topics}
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
        s, k, idx = _stamp(msg), cursor[topic], order[topic]
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


def check_usable(run: EstimationRun, bag: str | Path, namespace: str) -> None:
    """Raise :class:`~terrain_estimation.cli.InputError` when ``run`` estimated nothing, saying why.

    The message names the input topics the vehicle expects (with their types),
    which of them the bag holds, and what else it holds, so that a wrong
    ``--namespace``, a bag of another vehicle or a topic missing is seen at once;
    when inputs were read but every one was rejected, the reasons come with it.
    """
    if run.outputs:
        return
    expected = ", ".join(f"{t} ({m})" for t, m in run.expected_topics.items())
    if run.inputs_read == 0:
        found = [str(t) for t in bag_contents(bag).values() if t.count > 0]
        shown = ", ".join(found[:20]) + (f", … {len(found) - 20} more" if len(found) > 20 else "")
        raise InputError(
            f"no input message in {str(bag)!r} under namespace {namespace!r}: expected {expected}; "
            f"the bag holds {shown or 'no message at all'}"
        )
    missing = [t for t in run.expected_topics if not run.topics_read.get(t)]
    why = [f"{count} rejected: {reason}" for reason, count in sorted(run.rejected.items(), key=lambda kv: -kv[1])]
    if missing:
        why.insert(0, f"topics absent from the bag: {', '.join(missing)}")
    raise InputError(
        f"no estimate from {run.inputs_read} input messages of {str(bag)!r} "
        f"({run.accepted} accepted): " + ("; ".join(why[:8]) or "the estimator produced nothing")
    )


def _summary_lines(run: EstimationRun) -> Iterator[str]:
    truth_errs = streamed_truth_errors(run)  # read now: its undecodable messages belong to the counts below
    rejected = sum(run.rejected.values())
    yield f"input messages read: {run.inputs_read} ({run.accepted} accepted, {rejected} rejected)"
    for reason, count in sorted(run.rejected.items()):
        yield f"  rejected {count}: {reason}"
    missing = [t for t in run.expected_topics if not run.topics_read.get(t)]
    if missing:
        yield f"  topics absent from the bag: {', '.join(missing)}"
    if run.restarts:
        yield f"  estimator restarted {run.restarts} time(s) by the input checks"
    if run.divergences:
        beyond = f" ({run.limit_resets} beyond the vehicle's limits)" if run.limit_resets else ""
        yield f"  filter diverged {run.divergences} time(s){beyond}: caught and restarted"
    for reason, count in sorted(run.outputs_dropped.items()):
        yield f"  not written {count}: {reason}"
    yield from run.notes
    topics = sorted({t for t, _, _ in run.outputs})
    for topic in topics:
        msgs = run.messages(topic)
        yield f"{topic}: {len(msgs)} estimates"
        last = numeric_fields(msgs[-1])
        shown = ", ".join(f"{k}={v:.6g}" for k, v in list(last.items())[:8])
        yield f"  last: {shown}"
        for name, (rms, final, rel) in truth_errs.get(topic, {}).items():
            # A relative error above 1000 % says the truth is near zero (a sideslip on a straight run), not more.
            pct = f"{100 * rel:.2f} %" if rel <= 10.0 else "truth near 0"
            yield f"  vs ground truth {name}: rms error {rms:.6g}, final error {final:.6g} ({pct})"


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``--param NAME=VALUE`` items as ``{name: value}`` (values parsed as YAML, bounded: :func:`parse_override`)."""
    return dict(parse_override(item) for item in items)


def add_output_arguments(parser: argparse.ArgumentParser, *, output: str, overwrite: str, namespace: str) -> None:
    """The options of a tool that writes a vehicle's bag (``terrain-estimate``, ``terrain-simulate``).

    ``-o/--output``, ``--overwrite``, ``--namespace`` (with the help texts given), ``--config`` and
    ``--param NAME=VALUE`` (repeated; read with :func:`parse_overrides`).
    """
    parser.add_argument("-o", "--output", required=True, help=output)
    parser.add_argument("--overwrite", action="store_true", help=overwrite)
    parser.add_argument("--namespace", help=namespace)
    parser.add_argument("--config", help="parameter file (default: config/<vehicle>.yaml)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="override a parameter")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="terrain-estimate",
        description="Run a vehicle's estimator over a recorded rosbag2 bag and write the estimates to a new bag.",
        epilog="Exit status: 0 estimates written, 2 the input cannot be used (nothing written), 3 internal error.",
    )
    parser.add_argument("bag", help="input bag directory (mcap or sqlite3)")
    parser.add_argument("--vehicle", required=True, choices=sorted(VEHICLES), help="vehicle model")
    add_output_arguments(
        parser,
        output="output bag directory (must not exist; see --overwrite)",
        overwrite="replace the output if it is a previous bag (never the input)",
        namespace="namespace the bag was recorded under (default: the vehicle's)",
    )
    args = parser.parse_args(argv)

    def body() -> int:
        overrides = parse_overrides(args.param)
        # refused before the run, not after minutes of it
        check_output_path(args.output, overwrite=args.overwrite, inputs=[args.bag])
        print(f"estimating {args.bag} as {args.vehicle} ...", file=sys.stderr)
        namespace = args.namespace if args.namespace is not None else get_vehicle(args.vehicle).namespace
        run = estimate_bag(
            args.bag, args.vehicle, namespace=namespace, config=args.config, overrides=overrides, progress=True
        )
        for line in _summary_lines(run):
            print(line)
        check_usable(run, args.bag, namespace)
        with AtomicBagWriter(args.output, overwrite=args.overwrite, inputs=[args.bag]) as writer:
            writer.write_all(run.outputs)
        print(f"wrote {len(run.outputs)} messages to {args.output}")
        return EXIT_OK

    return run_cli("terrain-estimate", body, interrupted="interrupted; no output bag written")


if __name__ == "__main__":
    sys.exit(main())
