"""What ``terrain-batch`` does with one bag, and how it knows a bag is already done.

* :func:`find_bags` — the bags under the paths given (a bag directory holds a
  ``metadata.yaml`` or ``.mcap``/``.db3`` storage files; trees are walked).
* :func:`detect_vehicle` — which vehicle recorded a bag, from its topics,
  their types and their namespace (:func:`vehicle_inputs`).
* :func:`process_bag` — runs in a worker: detection, estimation
  (:func:`terrain_estimation.tools.estimate.estimate_bag`, the same path as
  ``terrain-estimate``) and/or diagnosis
  (:func:`terrain_analysis.sim2real.diagnose.diagnose`, as
  ``terrain-sim2real``), writes the bag's outputs and a manifest, and returns
  its summary row. Every failure is caught per stage and returned as the
  row's reason: the batch goes on.
* :func:`up_to_date` — runs in the client before anything is submitted: the
  manifest ``batch.json`` of an earlier run matches the bag's files (size and
  mtime, or, when only the mtime moved, their SHA-256), the tool version
  (the package version, and with ``code_key="sources"`` a digest of its
  sources), the parameter files and the options; then the bag is skipped and
  its earlier row reused. The row always names the sources that made it
  (column ``code``).

Layout of the output directory (one per input bag, under ``bags/``)::

    OUT/summary.csv, summary.parquet (if pyarrow), summary.md, summary.html
    OUT/bags/<bag path relative to the inputs' common root>/
        estimates/        the estimates bag (as terrain-estimate -o)
        diagnosis/        diagnosis.md, diagnosis.json[, figures] (as terrain-sim2real -o)
        batch.json        the fingerprint, options and row of the run that wrote them

The input bags are only ever read.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import json
import os
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "COLUMNS",
    "BagJob",
    "BatchOptions",
    "UnknownVehicleError",
    "bag_fingerprint",
    "code_version",
    "tool_version",
    "detect_vehicle",
    "failed_row",
    "find_bags",
    "process_bag",
    "up_to_date",
    "vehicle_inputs",
]

TOOL = "terrain-batch"
#: Bumped when the manifest or row layout changes: earlier outputs are then redone.
SCHEMA = 1
MANIFEST = "batch.json"
STORAGE_SUFFIXES = (".mcap", ".db3")
TASKS = ("estimate", "diagnose")

#: Columns of the summary table, in order (a row may lack none of them).
COLUMNS = (
    "bag",
    "status",
    "reason",
    "vehicle",
    "vehicle_from",
    "namespace",
    "duration_s",
    "messages_read",
    "messages_accepted",
    "estimates",
    "rejected",
    "rejections",
    "final_estimate",
    "verdict",
    "gap",
    "cpu_s",
    "estimate_cpu_s",
    "diagnose_cpu_s",
    "wall_s",
    "realtime_per_cpu",
    "worker",
    "finished",
    "input",
    "output",
    "code",
)


class UnknownVehicleError(ValueError):
    """No vehicle, or more than one, matches the bag's topics; the message lists what the bag holds."""


@dataclass(frozen=True)
class BatchOptions:
    """What is done to every bag (all of it enters the resumability key).

    Attributes:
        tasks: ``("estimate",)``, ``("diagnose",)`` or both.
        vehicle: the vehicle of every bag, or None to detect it per bag.
        namespace: the namespace of every bag, or None (the detected one, else the vehicle's default).
        config: parameter file for the estimators and the diagnosis, or None (``config/<vehicle>.yaml``).
        params: estimator overrides ``((name, value), ...)`` (``--param``; estimation only).
        figures: write the diagnosis figures (PNG).
    """

    tasks: tuple[str, ...] = ("estimate",)
    vehicle: str | None = None
    namespace: str | None = None
    config: str | None = None
    params: tuple[tuple[str, Any], ...] = ()
    figures: bool = False

    def key(self) -> dict[str, Any]:
        """The options as compared between runs (JSON-able)."""
        return {
            "tasks": list(self.tasks),
            "vehicle": self.vehicle,
            "namespace": self.namespace,
            "config": self.config,
            "params": [[k, repr(v)] for k, v in self.params],
            "figures": self.figures,
        }


@dataclass(frozen=True)
class BagJob:
    """One bag of a batch, as sent to a worker (picklable).

    Attributes:
        bag: absolute path of the input bag directory.
        rel: its path relative to the inputs' common root (names its output directory).
        out_dir: absolute path of its output directory (``OUT/bags/<rel>``).
        options: what to do (:class:`BatchOptions`).
        version: ``{"tool": tool_version()}`` (:func:`tool_version`).
    """

    bag: str
    rel: str
    out_dir: str
    options: BatchOptions
    version: Mapping[str, str] = field(default_factory=dict)

    def key(self) -> dict[str, Any]:
        return {"schema": SCHEMA, "version": dict(self.version), "options": self.options.key()}


# ---------------------------------------------------------------------------
# finding bags, fingerprints, versions
# ---------------------------------------------------------------------------


def _is_bag_dir(path: Path) -> bool:
    if (path / "metadata.yaml").is_file():
        return True
    try:
        return any(p.suffix in STORAGE_SUFFIXES and p.is_file() for p in path.iterdir())
    except OSError:
        return False


def find_bags(paths: Sequence[str | os.PathLike[str]]) -> tuple[list[tuple[Path, str]], list[tuple[Path, str]]]:
    """The bags under ``paths``: ``(found, missing)``, each as ``(absolute path, relative name)``.

    A path that is a bag directory (``metadata.yaml`` or a storage file in it), or a storage file (its
    directory), is one bag; any other directory is walked (hidden directories, e.g. a writer's
    ``.partial`` scratch, are skipped; a bag's own sub-directories are not searched). The relative names
    are the paths relative to the common root of all bags found (a single bag: its own name), so two
    bags of the same name in different places keep apart. ``missing`` lists paths that do not exist.
    """
    found: dict[Path, None] = {}
    missing: list[tuple[Path, str]] = []
    for item in paths:
        p = Path(item).absolute()
        if not p.exists():
            missing.append((p, p.name))
            continue
        if p.is_file() and p.suffix in STORAGE_SUFFIXES:
            p = p.parent
        if p.is_dir() and _is_bag_dir(p):
            found[p] = None
            continue
        for root, dirs, _files in os.walk(p):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            here = Path(root)
            if _is_bag_dir(here):
                found[here] = None
                dirs[:] = []
    bags = list(found)
    if not bags:
        return [], missing
    if len(bags) == 1:
        return [(bags[0], bags[0].name)], missing
    common = Path(os.path.commonpath([str(b) for b in bags]))
    return [(b, b.relative_to(common).as_posix()) for b in bags], missing


def bag_fingerprint(bag: str | os.PathLike[str], *, with_hash: bool = True) -> dict[str, dict[str, Any]]:
    """``{file name: {size, mtime_ns[, sha256]}}`` of the files of a bag directory (not recursive)."""
    out: dict[str, dict[str, Any]] = {}
    for p in sorted(Path(bag).iterdir()):
        if not p.is_file():
            continue
        st = p.stat()
        entry: dict[str, Any] = {"size": st.st_size, "mtime_ns": st.st_mtime_ns}
        if with_hash:
            entry["sha256"] = _sha256(p)
        out[p.name] = entry
    return out


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def tool_version(code_key: str = "version") -> str:
    """The tool version a result must match to be up to date.

    Args:
        code_key: ``"version"``: the package version (a release redoes the bags; an edit of the code in
            between does not, though each row names the sources that made it, :func:`code_version`);
            ``"sources"``: :func:`code_version`, so that any edit of the package's code redoes them.
    """
    if code_key == "sources":
        return code_version()
    if code_key != "version":
        raise ValueError(f"code_key must be 'version' or 'sources', got {code_key!r}")
    try:
        return f"terrain-estimation {importlib.metadata.version('terrain-estimation')}"
    except importlib.metadata.PackageNotFoundError:
        return "terrain-estimation unknown"


@functools.cache
def code_version() -> str:
    """``terrain-estimation <version> src:<digest>``: the package version and a digest of its sources.

    Computed once per process: the digest of the code a worker actually loaded.
    """
    import terrain_estimation

    root = Path(terrain_estimation.__file__).parent
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        h.update(p.relative_to(root).as_posix().encode())
        h.update(p.read_bytes())
    try:
        version = importlib.metadata.version("terrain-estimation")
    except importlib.metadata.PackageNotFoundError:
        version = "unknown"
    return f"terrain-estimation {version} src:{h.hexdigest()[:16]}"


def config_digest(config: str | None, vehicle: str | None) -> str:
    """SHA-256 (16 hex) of the parameter file a bag was processed with: ``config``, else ``vehicle``'s default.

    ``""`` when neither is known (a bag that failed before its vehicle was known).
    """
    from terrain_estimation.params import default_config_path

    if config:
        path = Path(config)
    elif vehicle:
        path = default_config_path(vehicle)
    else:
        return ""
    h = hashlib.sha256(path.name.encode())
    h.update(path.read_bytes() if path.is_file() else b"<absent>")
    return h.hexdigest()[:16]


def up_to_date(job: BagJob, *, retry_failed: bool = False) -> dict[str, Any] | None:
    """The row of an earlier run whose outputs are up to date with ``job``'s bag and options, else None.

    Up to date: ``batch.json`` exists in the bag's output directory, says ``done`` (or ``failed``,
    unless ``retry_failed``: the same files through the same code fail the same way), has the same key
    (schema, tool version, options), the parameter file it used (``--config``, else the default file of
    the bag's vehicle) is unchanged, its outputs still exist, and the bag holds the
    same files with the same sizes and either the same mtimes or, for a file whose mtime moved (a copy,
    a ``touch``), the same SHA-256.
    """
    manifest = Path(job.out_dir) / MANIFEST
    try:
        old = json.loads(manifest.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    accepted = ("done",) if retry_failed else ("done", "failed")
    if not isinstance(old, dict) or old.get("key") != job.key() or old.get("row", {}).get("status") not in accepted:
        return None
    for name in old.get("outputs", []):
        if not (Path(job.out_dir) / name).exists():
            return None
    if old.get("config_digest") != config_digest(job.options.config, old["row"].get("vehicle")):
        return None
    try:
        now = bag_fingerprint(job.bag, with_hash=False)
    except OSError:
        return None
    was: dict[str, dict[str, Any]] = old.get("fingerprint", {})
    if set(now) != set(was):
        return None
    for name, entry in now.items():
        if entry["size"] != was[name]["size"]:
            return None
        if entry["mtime_ns"] != was[name]["mtime_ns"] and _sha256(Path(job.bag) / name) != was[name].get("sha256"):
            return None
    row: dict[str, Any] = old["row"]
    return row


# ---------------------------------------------------------------------------
# vehicle detection
# ---------------------------------------------------------------------------


@functools.cache
def vehicle_inputs() -> dict[str, dict[str, str]]:
    """``{vehicle: {input topic relative to its namespace: message type}}`` of every known estimator.

    Read from each vehicle's adapter built with its parameters' declared defaults (once per process):
    no parameter names a topic, and a vehicle's config file (being edited, say) plays no part in
    recognising another vehicle's bag.
    """
    from terrain_estimation.bag import msgtype_name
    from terrain_estimation.params import resolve_parameters
    from terrain_estimation.ros.framework import EstimatorNode
    from terrain_estimation.vehicles import VEHICLES

    out: dict[str, dict[str, str]] = {}
    for name, entry in VEHICLES.items():
        defaults = resolve_parameters(tuple(EstimatorNode.COMMON_SPECS) + tuple(entry.specs), {}, strict=True)
        adapter = entry.make_adapter(defaults, entry.namespace)
        out[name] = {s.topic.lstrip("/"): msgtype_name(s.msg_type) for s in adapter.inputs}
    return out


def detect_vehicle(topics: Mapping[str, str], *, namespace: str | None = None) -> tuple[str, str, str]:
    """Which vehicle recorded a bag whose non-empty topics are ``{topic: message type}``.

    For every vehicle and every namespace under which at least one of its input topics appears with the
    contract's type, the inputs found are counted. Then, in order:

    1. a namespace whose last component is a vehicle's name (``/lrv``, ``/fleet/rover``) with at least
       one of that vehicle's inputs: that vehicle;
    2. otherwise the vehicles with *all* their inputs under one namespace, the most specific kept (the
       rover's inputs include the skid steer's, the quarter car's the LRV's): exactly one must remain.

    Args:
        topics: the bag's topics holding messages, with their types.
        namespace: only consider this namespace (``--namespace``).

    Returns:
        ``(vehicle, namespace, how)`` — ``how`` says which rule decided, for the summary.

    Raises:
        UnknownVehicleError: no vehicle matches, or several equally (two robots in one bag); the message
            names the bag's topics and each vehicle's expected inputs.
    """
    wanted = "/" + namespace.strip("/") if namespace is not None and namespace.strip("/") else namespace
    table = vehicle_inputs()
    matched: dict[tuple[str, str], int] = {}
    for vehicle, inputs in table.items():
        for rel, msgtype in inputs.items():
            for topic, found_type in topics.items():
                if not topic.endswith("/" + rel) or msgtype not in found_type.split(" | "):
                    continue
                ns = topic[: -len(rel) - 1]
                if wanted is not None and ns != wanted:
                    continue
                matched[vehicle, ns] = matched.get((vehicle, ns), 0) + 1
    named = sorted({(v, ns) for (v, ns) in matched if ns.rstrip("/").rsplit("/", 1)[-1] == v})
    if len(named) == 1:
        v, ns = named[0]
        return v, ns or "/", f"namespace {ns or '/'}"
    complete = [(v, ns) for (v, ns), n in matched.items() if n == len(table[v])]
    if named:
        raise UnknownVehicleError(
            "several vehicles' namespaces hold their inputs: "
            + ", ".join(f"{v} under {ns}" for v, ns in named)
            + "; pass --vehicle and --namespace"
        )
    # the most specific: drop a vehicle whose inputs are a strict subset of another complete one's
    kept = [
        (v, ns)
        for v, ns in complete
        if not any(set(table[v].items()) < set(table[w].items()) and ns == ns2 for w, ns2 in complete if w != v)
    ]
    if len(kept) == 1:
        v, ns = kept[0]
        return v, ns or "/", f"all {len(table[v])} input topics under {ns or '/'}"
    shown = ", ".join(f"{t} ({m})" for t, m in sorted(topics.items())[:12]) or "no message at all"
    if len(topics) > 12:
        shown += f", … {len(topics) - 12} more"
    if kept:
        raise UnknownVehicleError(
            "the topics fit several vehicles: "
            + ", ".join(f"{v} under {ns or '/'}" for v, ns in kept)
            + f" (the bag holds {shown}); pass --vehicle and --namespace"
        )
    expected = "; ".join(f"{v}: {', '.join(sorted(inp))}" for v, inp in table.items())
    where = f" under namespace {wanted}" if wanted is not None else ""
    raise UnknownVehicleError(
        f"no known vehicle's input topics{where} (expected, under any namespace: {expected}); the bag holds {shown}"
    )


# ---------------------------------------------------------------------------
# one bag
# ---------------------------------------------------------------------------


def _short(exc: BaseException, limit: int = 400) -> str:
    text = f"{type(exc).__name__}: {exc}".replace("\n", " ")
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _bag_duration(bag: str) -> float:
    from rosbags.rosbag2 import Reader

    with Reader(Path(bag)) as reader:
        return float(reader.duration) * 1e-9


def empty_row(job: BagJob) -> dict[str, Any]:
    row: dict[str, Any] = dict.fromkeys(COLUMNS, None)
    row.update(bag=job.rel, input=job.bag, output=job.out_dir, rejections="{}", status="failed", reason="")
    return row


def failed_row(job: BagJob, reason: str, *, cpu_s: float = 0.0, worker: str = "") -> dict[str, Any]:
    """The row of a bag whose task never returned (its worker died): status ``failed`` with ``reason``."""
    row = empty_row(job)
    row.update(reason=reason, cpu_s=cpu_s, worker=worker, finished=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
    return row


def _final_estimate(run: Any) -> str:
    """``field=value`` of the last estimate of each estimate topic with ground-truth fields (else its first 6)."""
    from terrain_estimation.tools.estimate import numeric_fields

    parts = []
    topics = sorted({t for t, _, _ in run.outputs})
    with_truth = [t for t in topics if run.truth_fields.get(t)]
    for topic in with_truth or topics:
        msgs = run.messages(topic)
        values = numeric_fields(msgs[-1])
        fields = run.truth_fields.get(topic) or tuple(values)[:6]
        parts.append(f"{topic.rsplit('/', 1)[-1]}: " + ", ".join(f"{k}={values[k]:.6g}" for k in fields if k in values))
    return "; ".join(parts)


def process_bag(job: BagJob) -> dict[str, Any]:
    """Do ``job``'s tasks on its bag in this process; return the summary row (never raises an ``Exception``).

    The row's ``status`` is ``done`` when every task succeeded, else ``failed`` with ``reason`` naming
    the stage and the error; what a stage that succeeded wrote is kept. Either way ``batch.json``
    records it (once the bag's files could be listed), so that an unchanged bag is not redone next time
    (:func:`up_to_date`; a failure is retried on request). CPU and wall time are filled in by the engine.
    """
    from terrain_estimation.bag import bag_contents

    row = empty_row(job)
    opts = job.options
    stage = "reading the bag"
    fingerprint: dict[str, Any] | None = None
    try:
        fingerprint = bag_fingerprint(job.bag)
        row["duration_s"] = _bag_duration(job.bag)
        topics = {t.topic: t.msgtype for t in bag_contents(job.bag).values() if t.count > 0}
        stage = "detecting the vehicle"
        if opts.vehicle is not None:
            from terrain_estimation.vehicles import get_vehicle

            vehicle = opts.vehicle
            namespace = opts.namespace if opts.namespace is not None else get_vehicle(vehicle).namespace
            row["vehicle_from"] = "--vehicle"
        else:
            vehicle, namespace, how = detect_vehicle(topics, namespace=opts.namespace)
            row["vehicle_from"] = how
        row["vehicle"], row["namespace"] = vehicle, namespace
        out = Path(job.out_dir)
        outputs: list[str] = []
        if "estimate" in opts.tasks:
            stage = "estimating"
            _estimate(job, vehicle, namespace, out, row)
            outputs.append("estimates")
        if "diagnose" in opts.tasks:
            stage = "diagnosing"
            _diagnose(job, vehicle, namespace, out, row)
            outputs.append("diagnosis")
    except Exception as exc:  # isolation: any failure of this bag is its row's reason; the batch goes on
        row["reason"] = f"{stage}: {_short(exc)}"
        row["finished"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        row["code"] = code_version()
        if fingerprint is not None:  # the same bag with the same tool fails the same way: remembered
            try:
                _write_manifest(job, fingerprint, [], row)
            except Exception:  # e.g. an output directory this tool did not make: the failure is not remembered
                pass
        return row
    row["status"] = "done"
    row["finished"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    row["code"] = code_version()
    try:
        _write_manifest(job, fingerprint, outputs, row)
    except Exception as exc:  # the outputs are written but the run cannot be recorded: redone next time
        row["status"] = "failed"
        row["reason"] = f"writing {MANIFEST}: {_short(exc)}"
    return row


def _write_manifest(job: BagJob, fingerprint: dict[str, Any], outputs: list[str], row: Mapping[str, Any]) -> None:
    from terrain_estimation.outputs import prepare_output_dir

    out = prepare_output_dir(job.out_dir, inputs=[job.bag], tool=TOOL)
    manifest = {
        "tool": TOOL,
        "key": job.key(),
        "config_digest": config_digest(job.options.config, row.get("vehicle")),
        "fingerprint": fingerprint,
        "outputs": outputs,
        "row": dict(row),
    }
    partial = out / f".{MANIFEST}.partial-{os.getpid()}"
    partial.write_text(json.dumps(manifest, indent=1, default=str) + "\n", encoding="utf-8")
    os.replace(partial, out / MANIFEST)


def _estimate(job: BagJob, vehicle: str, namespace: str, out: Path, row: dict[str, Any]) -> None:
    from terrain_estimation.bag import AtomicBagWriter
    from terrain_estimation.outputs import prepare_output_dir
    from terrain_estimation.tools.estimate import check_usable, estimate_bag

    cpu0 = time.process_time()
    run = estimate_bag(
        job.bag,
        vehicle,
        namespace=namespace,
        config=job.options.config,
        overrides=dict(job.options.params) or None,
    )
    row["messages_read"] = run.inputs_read
    row["messages_accepted"] = run.accepted
    row["rejected"] = sum(run.rejected.values())
    row["rejections"] = json.dumps(dict(sorted(run.rejected.items(), key=lambda kv: -kv[1])), ensure_ascii=False)
    row["estimates"] = len(run.outputs)
    check_usable(run, job.bag, namespace)
    row["final_estimate"] = _final_estimate(run)
    prepare_output_dir(out, inputs=[job.bag], tool=TOOL)  # refuses a directory this tool did not make
    # replaces only a previous estimates bag, inside the directory this tool made
    with AtomicBagWriter(out / "estimates", overwrite=True, inputs=[job.bag]) as writer:
        writer.write_all(run.outputs)
    row["estimate_cpu_s"] = time.process_time() - cpu0


def _diagnose(job: BagJob, vehicle: str, namespace: str, out: Path, row: dict[str, Any]) -> None:
    from terrain_analysis.sim2real.diagnose import diagnose
    from terrain_analysis.sim2real.report import write_diagnosis
    from terrain_estimation.outputs import prepare_output_dir

    cpu0 = time.process_time()
    result = diagnose(job.bag, vehicle, namespace=namespace, config=job.options.config)
    row["verdict"] = result.verdict
    row["gap"] = result.attribution.kind
    if row["duration_s"] is None:
        row["duration_s"] = result.duration
    prepare_output_dir(out, inputs=[job.bag], tool=TOOL)
    target = prepare_output_dir(out / "diagnosis", inputs=[job.bag], tool=TOOL)
    write_diagnosis(result, target, figures=job.options.figures)
    row["diagnose_cpu_s"] = time.process_time() - cpu0


def rows_jsonable(rows: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Rows with every column present, in :data:`COLUMNS` order."""
    return [{c: r.get(c) for c in COLUMNS} for r in rows]


def job_dict(job: BagJob) -> dict[str, Any]:
    return asdict(job)
