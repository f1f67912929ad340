"""``terrain-estimate BAG --vehicle V -o OUT_BAG``: estimate from a recorded bag.

Runs the vehicle's adapter and filter over the bag's sensor topics with no
ROS graph, in the bag's recorded order (the order a live replay publishes
them), and writes the estimates to a new bag, atomically. The estimates are
identical to those of the live node fed the same messages: both go through
the same adapter (tested in ``test/test_live_offline.py``). Each estimate is
written as it is made (:func:`estimate_to_bag`): memory does not grow with the
bag's length.

A summary goes to stdout: messages read, rejected (by reason) and written, what
the vehicle's adapter says about the run (its ``summary_lines()``, if it has
one: e.g. the skid steer's wheel-speed lookup and measured rate), the last
estimate, and, when the bag carries ``ground_truth/<topic>`` for an estimate
topic (a simulator's bag), the error of every numeric field against it
(:mod:`terrain_estimation.tools.estimate_truth`, read in the same pass).

``--config`` may be a file that describes another model of the vehicle in its
``/**`` section (``vehicle.kind`` other than the estimator's, e.g.
``config/husky.yaml``: the 4-wheel Husky of the sim-to-real replay) and the
estimator's view in the estimator's own section: then, as rcl applies such a
file to the node, the names of ``/**`` the estimator declares are taken, the
others are left to the file's other readers, and the estimator's section
(checked strictly) goes over them (:func:`config_values`,
:mod:`terrain_estimation.config_sections`).

A message rejected by the input checks, or whose bytes do not decode, is
counted and the run goes on: the bag then holds every estimate made. A run
that stops (an unreadable bag, an internal error, Ctrl-C) or estimates nothing
leaves no output bag (the partial one is removed).

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
import os
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from terrain_estimation.bag import AtomicBagWriter, bag_contents, msgtype_name, read_bag
from terrain_estimation.cli import EXIT_OK, InputError, run_cli
from terrain_estimation.config_sections import describes_another_kind, node_file_values
from terrain_estimation.outputs import check_output_path
from terrain_estimation.params import ParamValue, parse_override, resolve_parameters
from terrain_estimation.ros.validation import InputGuard
from terrain_estimation.tools.estimate_replay import Replay, Sink, TruthSink, replay_bulk, replay_messages
from terrain_estimation.tools.estimate_stream import StreamedEstimates
from terrain_estimation.tools.estimate_truth import numeric_fields, streamed_truth_errors, truth_errors
from terrain_estimation.vehicles import VEHICLES, estimator_parameters, get_vehicle

__all__ = [
    "EstimationRun",
    "add_output_arguments",
    "config_values",
    "estimate_bag",
    "estimate_to_bag",
    "run_adapter",
    "main",
    "numeric_fields",
    "parse_overrides",
    "streamed_truth_errors",
    "topic_name",
    "truth_errors",
]


def topic_name(namespace: str, relative: str) -> str:
    """Absolute topic of ``relative`` under ``namespace``."""
    if relative.startswith("/"):
        return relative
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{relative}"


@dataclass
class EstimationRun:
    """What an offline run produced (messages in output order).

    ``truth`` (a simulator's ``ground_truth/<topic>`` messages, by estimate topic) is read from the bag
    on first access, not during the run: only a summary against ground truth needs it, and decoding it
    during the replay cost as much as decoding the inputs (undecodable truth messages are counted in
    ``rejected`` when it is read).

    A run with a sink (:func:`estimate_to_bag`) keeps no output: ``outputs`` stays empty and ``streamed``
    counts the estimates handed to the sink.
    """

    outputs: list[tuple[str, Any, int]] = field(default_factory=list)  # (topic, msg, log time ns)
    streamed: int = 0  # estimates handed to a sink instead of kept in ``outputs``
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
    sink: Sink | None = None,
    truth: TruthSink | None = None,
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

    With a ``sink``, each estimate kept goes to it as it is made, not to ``run.outputs``; with ``truth``,
    the ground-truth topics are read in the same pass and each of their decoded messages goes to it, in
    recorded order, as ``truth(bag topic, message)`` (not with ``previous``).

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
    # ``previous``: the truth decoded in the same pass, as the previous path did (benchmarks); ``truth``: too.
    if previous and truth is not None:
        raise ValueError("run_adapter: a truth sink is not taken on the previous path")
    read = list(inputs) + (list(truth_topics) if previous or truth is not None else [])
    eager: dict[str, list[Any]] = {}
    # The cyclic garbage collector is paused for the replay (not on the previous path): the run keeps every
    # output message, and the collector's full passes traverse them again and again (a fifth of the CPU of
    # a 60 s skid-steer replay). The replay's objects (messages, estimates) hold no reference cycles;
    # whatever cycles it makes (an exception's traceback) are collected when the collector resumes.
    collecting = gc.isenabled()
    if not previous:
        gc.disable()
    try:
        replay = Replay(run, adapter, bag, read, types, undecodable, inputs, outputs, guard, progress, sink, truth)
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
    stream: StreamedEstimates | None = None,
) -> EstimationRun:
    """Run ``vehicle``'s estimator over ``bag`` (see :func:`run_adapter`).

    Args:
        reference: the previous path, for benchmarks and tests that compare the two: the reference
            (Python) filter step where an adapter also has a compiled one (``adapter.set_compiled(False)``:
            the skid steer's), the ground truth decoded during the run, the garbage collector running
            (:func:`run_adapter`). The estimates agree to rounding.
        bulk: the numeric inputs decoded and checked in bulk (the default; False: one message at a time, as
            before; the same estimates, bit for bit: :func:`run_adapter`).
        stream: each estimate goes to it as it is made, none is kept in ``run.outputs``, and the ground
            truth is read in the same pass (:func:`estimate_to_bag`; not with ``reference``).
    """
    entry = get_vehicle(vehicle)
    ns = namespace if namespace is not None else entry.namespace
    values = config_values(entry, config, overrides)
    adapter = entry.make_adapter(values, ns)
    set_compiled = getattr(adapter, "set_compiled", None)
    if reference and callable(set_compiled):
        set_compiled(False)
    if stream is not None:
        _expect_truth(stream, adapter, ns, bag)
    run = run_adapter(
        adapter,
        ns,
        bag,
        progress=progress,
        values=values,
        previous=reference,
        bulk=bulk,
        sink=stream,
        truth=stream.truth if stream is not None else None,
    )
    health = getattr(getattr(adapter, "health", None), "values", {})
    run.divergences = int(health.get("divergences", 0))
    run.limit_resets = int(health.get("limit_resets", 0))
    summary = getattr(adapter, "summary_lines", None)
    run.notes = list(summary()) if callable(summary) else []
    return run


def estimate_to_bag(
    bag: str | Path,
    vehicle: str,
    output: str | Path,
    *,
    namespace: str | None = None,
    config: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    overwrite: bool = False,
    progress: bool = False,
    report: Callable[[str], None] | None = None,
) -> tuple[EstimationRun, int]:
    """:func:`estimate_bag` writing each estimate to the bag ``output`` as it is made; the run and the
    messages written.

    The bag holds what :func:`estimate_bag`'s ``run.outputs`` would, written by the same
    :class:`~terrain_estimation.bag.AtomicBagWriter` in the same order, and memory does not grow with the
    bag: no estimate is kept (``run.outputs`` stays empty; ``run.streamed`` counts them), the ground truth is
    compared in the same pass with running sums (:class:`~terrain_estimation.tools.estimate_stream.StreamedEstimates`).
    ``report`` is given the summary's lines (:func:`_summary_lines`, the same text) before the bag is closed.

    ``output`` is checked as :class:`~terrain_estimation.bag.AtomicBagWriter` does (``overwrite``: a previous
    bag may be replaced; never an input or anything else). The bag is moved into place only when the run
    ends with estimates; otherwise the partial bag is removed, and so are the empty parent directories the
    writer made, and ``output`` is left as it was.

    Raises:
        InputError: no estimate at all (:func:`check_usable`).
        BagError: the bag is unreadable (found at its end: nothing is written).
    """
    ns = namespace if namespace is not None else get_vehicle(vehicle).namespace
    made = _missing_parents(Path(output))
    try:
        with AtomicBagWriter(output, overwrite=overwrite, inputs=[bag]) as writer:
            stream = StreamedEstimates(writer)
            run = estimate_bag(
                bag, vehicle, namespace=ns, config=config, overrides=overrides, progress=progress, stream=stream
            )
            for line in _summary_lines(run, stream):
                if report is not None:
                    report(line)
            check_usable(run, bag, ns)
        return run, writer.count
    except BaseException:
        for parent in made:  # deepest first; one that holds anything stays
            try:
                os.rmdir(parent)
            except OSError:
                break
        raise


def _missing_parents(path: Path) -> list[Path]:
    """The parent directories of ``path`` that do not exist, deepest first."""
    missing = []
    parent = path.absolute().parent
    while not parent.exists() and parent != parent.parent:
        missing.append(parent)
        parent = parent.parent
    return missing


def _expect_truth(stream: StreamedEstimates, adapter: Any, namespace: str, bag: str | Path) -> None:
    """Tell ``stream`` the ground truth of ``adapter``'s estimates (:meth:`StreamedEstimates.expect`)."""
    truth_topics = {
        topic_name(namespace, "ground_truth/" + s.topic): topic_name(namespace, s.topic) for s in adapter.outputs
    }
    try:
        present = {t.topic for t in bag_contents(bag).values() if t.count > 0}
    except Exception:  # the replay's reader says what is wrong with the bag, in its own words
        present = set()
    fields = {topic_name(namespace, s.topic): tuple(s.truth_fields) for s in adapter.outputs}
    stream.expect(truth_topics, fields, present)


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


def check_usable(run: EstimationRun, bag: str | Path, namespace: str) -> None:
    """Raise :class:`~terrain_estimation.cli.InputError` when ``run`` estimated nothing, saying why.

    The message names the input topics the vehicle expects (with their types),
    which of them the bag holds, and what else it holds, so that a wrong
    ``--namespace``, a bag of another vehicle or a topic missing is seen at once;
    when inputs were read but every one was rejected, the reasons come with it.
    """
    if run.outputs or run.streamed:
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


def _summary_lines(run: EstimationRun, stream: StreamedEstimates | None = None) -> Iterator[str]:
    """What ``terrain-estimate`` prints: counts, the adapter's notes, per estimate topic its count, its last
    estimate and its errors against ground truth (from ``run.outputs``, or from ``stream`` for a streamed run)."""
    if stream is None:
        truth_errs = streamed_truth_errors(run)  # read now: its undecodable messages belong to the counts below
        counts: dict[str, int] = {}
        last: dict[str, Any] = {}
        for topic, msg, _ in run.outputs:
            counts[topic] = counts.get(topic, 0) + 1
            last[topic] = msg
    else:
        truth_errs, counts, last = stream.truth_errors(), stream.counts, stream.last
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
    for topic in sorted(counts):
        yield f"{topic}: {counts[topic]} estimates"
        shown = ", ".join(f"{k}={v:.6g}" for k, v in list(numeric_fields(last[topic]).items())[:8])
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
        _, written = estimate_to_bag(
            args.bag,
            args.vehicle,
            args.output,
            namespace=namespace,
            config=args.config,
            overrides=overrides,
            overwrite=args.overwrite,
            progress=True,
            report=print,
        )
        print(f"wrote {written} messages to {args.output}")
        return EXIT_OK

    return run_cli("terrain-estimate", body, interrupted="interrupted; no output bag written")


if __name__ == "__main__":
    sys.exit(main())
