"""The scaffolding every blind-suite generator shares, and no physics.

A blind suite is a directory of bags, ``manifest.json`` (bag id → vehicle and
bag, what the diagnosis is given) and ``labels.json`` (what each bag holds, for
the scorer only). Two generators write one: this package's independent one
(:mod:`vehicle_sim.independent.suite`) and the simulator's own
(:mod:`vehicle_sim.tools.withheld`). What they share is here: seeded draws,
the check of a request, running the plans (in worker processes or not),
writing the two JSON files and the command line's ending.

This module imports nothing of the simulator or the core, so the independent
generator stays independent of them (``test_independent_generator.py``).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import math
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from pathlib import Path
from typing import Any, NamedTuple, Protocol, TypeVar

import numpy as np

__all__ = [
    "BagDraw",
    "SuitePlan",
    "check_request",
    "draw_bag",
    "g4",
    "keep_some",
    "log_uniform",
    "map_jobs",
    "run_generator",
    "run_suite_cli",
    "unique_id",
    "vehicle_rng",
    "worker_pool",
    "write_json",
    "write_manifest_and_labels",
]

W = TypeVar("W")
R = TypeVar("R")
P = TypeVar("P", bound="SuitePlan")


class SuitePlan(Protocol):
    """What the suite's index needs of a bag plan."""

    @property
    def id(self) -> str: ...

    @property
    def vehicle(self) -> str: ...

    @property
    def path(self) -> str: ...

    def label(self) -> dict[str, Any]: ...


# ---------------------------------------------------------------------------
# Seeded draws
# ---------------------------------------------------------------------------


def vehicle_rng(seed: int, tag: str) -> np.random.Generator:
    """The generator of one vehicle's plans: the master seed and a hash of ``tag``."""
    tag_hash = int.from_bytes(hashlib.sha256(tag.encode()).digest()[:4], "little")
    return np.random.default_rng([int(seed), tag_hash])


def unique_id(rng: np.random.Generator, ids: set[str]) -> str:
    """A new 12-hex-digit bag id not in ``ids`` (added to it)."""
    bag_id = rng.bytes(6).hex()
    while bag_id in ids:
        bag_id = rng.bytes(6).hex()
    ids.add(bag_id)
    return bag_id


class BagDraw(NamedTuple):
    """The draws that open every bag's plan (see :func:`draw_bag`)."""

    id: str
    duration: float
    scenario: dict[str, Any]
    seed: int
    start_time_ns: int


def draw_bag(
    rng: np.random.Generator,
    ids: set[str],
    vehicle: str,
    rough: bool,
    *,
    durations: tuple[float, float],
    duration: float | None,
    start_range_s: tuple[float, float],
    scenario: Callable[[str, np.random.Generator, bool], dict[str, Any]],
) -> BagDraw:
    """A bag's id, duration, scenario, noise seed and start time, drawn from ``rng`` in that order.

    The duration is ``duration`` when given, else uniform in ``durations``
    (s, rounded to 0.01 s); ``scenario(vehicle, rng, rough)`` draws the
    scenario; the start time is uniform in ``start_range_s`` (s since the
    epoch, returned in ns).
    """
    bag_id = unique_id(rng, ids)
    lo, hi = durations
    length = float(duration) if duration is not None else round(float(rng.uniform(lo, hi)), 2)
    drawn = scenario(vehicle, rng, rough)
    bag_seed = int(rng.integers(2**31 - 1))
    start = int(rng.integers(int(start_range_s[0] * 1e9), int(start_range_s[1] * 1e9)))
    return BagDraw(bag_id, length, drawn, bag_seed, start)


def keep_some(rng: np.random.Generator, count: int) -> list[bool]:
    """Which of ``count`` components to keep: each with probability ½, at least one (chosen at random)."""
    keep = [bool(rng.random() < 0.5) for _ in range(count)]
    if not any(keep):
        keep[int(rng.integers(count))] = True
    return keep


def log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    """A draw uniform in log between ``low`` and ``high`` (> 0)."""
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def g4(x: float) -> float:
    """``x`` rounded to 4 significant digits (the signatures in labels.json)."""
    return float(f"{x:.4g}")


def check_request(
    vehicles: Sequence[str],
    known: Sequence[str],
    catalogue: Mapping[str, Iterable[str]],
    effects: Sequence[str] | None,
    duration: float | None,
    shortest: float,
) -> None:
    """Refuse a fixed duration not above ``shortest`` (s), a vehicle not in ``known``, or an effect none of
    ``vehicles`` has in ``catalogue`` (vehicle → its effect names)."""
    if duration is not None and not duration > shortest:
        raise ValueError(f"duration must be > {shortest:g} s, got {duration}")
    for v in vehicles:
        if v not in known:
            raise ValueError(f"unknown vehicle {v!r}; known: {', '.join(known)}")
    if effects is not None:
        offered = {name for v in vehicles for name in catalogue[v]}
        unknown = sorted(set(effects) - offered)
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown} for vehicles {list(vehicles)}; known: {sorted(offered)}")


# ---------------------------------------------------------------------------
# Running the plans and writing the index
# ---------------------------------------------------------------------------


def worker_pool(jobs: int) -> contextlib.AbstractContextManager[Executor | None]:
    """A pool of ``jobs`` worker processes, or None (run in this process) for ``jobs`` ≤ 1."""
    if jobs <= 1:
        return contextlib.nullcontext()
    return ProcessPoolExecutor(max_workers=jobs)


def map_jobs(function: Callable[[W], R], work: Iterable[W], pool: Executor | None) -> Iterator[R]:
    """``function`` over ``work`` in order: lazily in this process (``pool`` None) or in the pool."""
    return map(function, work) if pool is None else pool.map(function, work)


def write_json(path: Path, data: Any) -> None:
    """Write ``data`` as sorted, indented JSON; a partial file never takes ``path``'s place."""
    tmp = path.with_name(f".{path.name}.partial")
    tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    tmp.replace(path)


def write_manifest_and_labels(
    root: Path,
    plans: Sequence[SuitePlan],
    results: Mapping[str, Mapping[str, Any]],
    manifest: dict[str, Any],
    labels: dict[str, Any],
) -> None:
    """Write ``manifest.json`` and ``labels.json`` under ``root``, bags in id order.

    ``manifest`` and ``labels`` hold the generator's own entries (notes and the
    like); this adds the bags (id, vehicle, bag path) to the first and each
    plan's label, with its ``signature`` when ``results[id]`` has one, to the
    second.
    """
    ordered = sorted(plans, key=lambda p: p.id)
    manifest["bags"] = [{"id": p.id, "vehicle": p.vehicle, "bag": p.path} for p in ordered]
    labels["labels"] = {}
    for p in ordered:
        label = p.label()
        if "signature" in results[p.id]:
            label["signature"] = results[p.id]["signature"]
        labels["labels"][p.id] = label
    write_json(root / "manifest.json", manifest)
    write_json(root / "labels.json", labels)


def run_generator(
    prog: str,
    out: str,
    vehicles: Sequence[str],
    plan: Callable[[], Sequence[P]],
    generate: Callable[[Sequence[P]], Mapping[str, Any]],
    errors: tuple[type[Exception], ...],
) -> int:
    """The command line's ending: plan, generate, and say what was written; 2 on ``errors``, 130 on Ctrl-C."""
    try:
        plans = plan()
        if not plans:
            raise ValueError("nothing to generate (all counts are 0)")
        print(f"{prog}: generating {len(plans)} bags for {', '.join(vehicles)} in {out}", file=sys.stderr)
        summary = generate(plans)
    except errors as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; the suite is incomplete", file=sys.stderr)
        return 130
    print(
        f"wrote {summary['bags']} bags in {summary['seconds']:.1f} s to {out} "
        "(manifest.json for the diagnosis, labels.json for the scorer only)"
    )
    return 0


def run_suite_cli(
    prog: str,
    args: argparse.Namespace,
    known: tuple[str, ...],
    plan_suite: Callable[..., Sequence[P]],
    generate: Callable[..., Mapping[str, Any]],
    errors: tuple[type[Exception], ...],
    *,
    plan_options: Mapping[str, Any] | None = None,
    generate_options: Mapping[str, Any] | None = None,
) -> int:
    """:func:`run_generator` on the options every blind-suite command line has.

    ``args`` holds ``out``, ``seed``, ``vehicle`` (the vehicles, once each in
    the order given; None for all ``known``), ``per_effect``, ``controls``,
    ``out_of_catalogue``, ``effect``, ``duration``, ``jobs`` and
    ``no_signature``; they become
    ``plan_suite(seed, vehicles, per_effect=, controls=, out_of_catalogue=,
    effects=, duration=, **plan_options)`` and ``generate(out, plans, jobs=,
    signatures=, **generate_options)``.
    """
    vehicles = tuple(dict.fromkeys(args.vehicle)) if args.vehicle else known
    return run_generator(
        prog,
        args.out,
        vehicles,
        lambda: plan_suite(
            args.seed,
            vehicles,
            per_effect=args.per_effect,
            controls=args.controls,
            out_of_catalogue=args.out_of_catalogue,
            effects=args.effect,
            duration=args.duration,
            **(plan_options or {}),
        ),
        lambda plans: generate(
            args.out,
            plans,
            jobs=max(1, args.jobs),
            signatures=not args.no_signature,
            **(generate_options or {}),
        ),
        errors,
    )
