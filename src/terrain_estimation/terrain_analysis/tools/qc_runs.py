"""The quarter-car reproduction's runs: what one ride is, its seeds, the plan, and the metrics of an estimate.

Scenario definitions of ``python -m terrain_analysis.tools.reproduce_qc``
(:mod:`~terrain_analysis.tools.reproduce_qc` has the cases and the page):
a :class:`RunSpec` is one simulated ride (road, soils, speed, duration) with
the estimator :class:`Variant` s run over the same sensor data;
:func:`build_plan` lists every ride of the reproduction; :func:`run_one`
simulates one and returns a :class:`Trace` per variant. The metrics
(:func:`rmse`, :func:`mean_abs`, :func:`settle_time`) are defined on a trace.

Seeds: run ``i`` of case group ``c`` uses
``SeedSequence([8608, c, i]).generate_state(2)`` → (road seed, sensor-noise
seed); variants of one run (filters, noise forms, profile rates, lift-off) see
the same road and the same sensor noise (paired comparison). Groups: 1 =
Graneville ISO D (cases 1, 6, 7, 8), 2 = Table 4, 3 = LETE ISO F, 4 =
Meadow-c, 5 = LRV, 6 / 7 = the no-change rides of the quarter car / LRV
(case 2c, :data:`GROUP_NOCHANGE`, :data:`GROUP_NOCHANGE_LRV`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal, TypeVar

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.reporting import Report
from terrain_analysis.reporting import format_number as _fmt
from terrain_analysis.reporting import in_window as _window
from terrain_analysis.reporting import summary_stats as _stats
from terrain_estimation.estimators.soil_stiffness import SoilStiffnessEstimator, SoilStiffnessEstimatorConfig
from terrain_estimation.models.quarter_car import LRVParams, QuarterCarParams
from vehicle_sim.plants.quarter_car import LRVVehicle, QuarterCarVehicle, Scenario, SpeedProfile, simulate
from vehicle_sim.terrain.profiles import RoadProfile, iso8608_profile, meadow_c_standin
from vehicle_sim.terrain.soils import SoilPath, soil_by_name

__all__ = [
    "ROOT_SEED",
    "Counts",
    "GROUP_NOCHANGE",
    "GROUP_NOCHANGE_LRV",
    "NOCHANGE_SOILS",
    "PROFILE_RATES",
    "Results",
    "RunSpec",
    "TABLE4_CELLS",
    "Trace",
    "Variant",
    "build_plan",
    "collect",
    "mean_abs",
    "node_default_config",
    "rmse",
    "run_one",
    "run_seeds",
    "settle_time",
]

ROOT_SEED = 8608
"""Root of every seed of the reproduction (see the module docstring)."""

FloatArray = NDArray[np.float64]

# Case groups for the seeds (cases 1, 6, 7, 8 share the realisations of group 1).
_GROUP_GRANEVILLE = 1
_GROUP_TABLE4 = 2
_GROUP_LETE = 3
_GROUP_MEADOW = 4
_GROUP_LRV = 5

_PATH_SOILS = ("lete_sand", "upland_sandy_loam", "graneville_loam")
_QC_WALK = QuarterCarParams().q_ktot_per_step  # (N/m)² per 10 ms, reported as used
_LRV_WALK = LRVParams().q_ktot_per_step
_HALF_STEP = 0.005  # half a filter period (s): window ends that exclude the sample at a soil change
_K_T = 175.0e3
_START_S = 2.0  # start transient (s) excluded from the soil-change statistic's maximum

# ---------------------------------------------------------------------------
# What one run is
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Variant:
    """One estimator configuration run over a simulated ride.

    Attributes:
        label: key of the variant in the results.
        filter: ``"sckf"`` or ``"ekf"``.
        noise_form: k_tot process noise, ``"per_step"`` (default, 1e3 (N/m)²
            per 10 ms) or ``"printed"`` (Δt³σ5², MODELS.md A.4).
        jacobian: EKF Jacobian, ``"exact"`` or ``"paper"`` (omits ∂(B u)/∂k_tot).
        change_frac: the estimator's soil-change re-open of the k_tot variance;
            0 is the paper's filter (used everywhere except the rows that say
            "project estimator").
        relative_damper: LRV model with the damper on ẏ1 − ḣ (matches the
            default LRV truth) instead of the paper's literal reduction.
        stiffness_state: ``"k_tot"`` (the paper's augmented state) or
            ``"log_k_s"`` (s = ln(k_s/k_series): k_tot stays inside
            (0, k_series) for every cubature point).
        change_log_std: the soil-change re-open for the ``"log_k_s"`` state
            (std of ln k_s added); 0 disables.
        node_defaults: ignore every other field but ``label``: the estimator
            node's parameter defaults (``config/<vehicle>.yaml``), soil-change
            detector and its innovation-sized re-open included.
    """

    label: str
    filter: Literal["sckf", "ekf"] = "sckf"
    noise_form: Literal["per_step", "printed"] = "per_step"
    jacobian: Literal["exact", "paper"] = "exact"
    change_frac: float = 0.0
    relative_damper: bool = True
    stiffness_state: Literal["k_tot", "log_k_s"] = "k_tot"
    change_log_std: float = 0.0
    node_defaults: bool = False

    def config(self, vehicle: str) -> SoilStiffnessEstimatorConfig:
        """The estimator configuration of this variant for ``vehicle``."""
        if self.node_defaults:
            return node_default_config(vehicle)
        # The paper's filter: a fixed re-open (0 = none), no move of the mean
        # (change_reopen_scale = change_jump_gain = 0).
        model: dict[str, Any]
        if vehicle == "lrv":
            model = {
                "vehicle": "lrv",
                "lrv": LRVParams(
                    relative_damper=self.relative_damper,
                    ktot_noise_form=self.noise_form,
                    ekf_jacobian=self.jacobian,
                    stiffness_state=self.stiffness_state,
                ),
            }
        else:
            model = {
                "vehicle": "quarter_car",
                "quarter_car": QuarterCarParams(
                    ktot_noise_form=self.noise_form, ekf_jacobian=self.jacobian, stiffness_state=self.stiffness_state
                ),
            }
        return SoilStiffnessEstimatorConfig(
            **model,
            filter=self.filter,
            change_ktot_std_frac=self.change_frac,
            change_log_ks_std=self.change_log_std,
            change_reopen_scale=0.0,
            change_jump_gain=0.0,
        )


def node_default_config(vehicle: str) -> SoilStiffnessEstimatorConfig:
    """The estimator configuration the node builds from its parameter defaults for ``vehicle``."""
    from terrain_estimation.ros.soil_stiffness import estimator_config, specs_for

    return estimator_config({spec.name: spec.default for spec in specs_for(vehicle)})


@dataclass(frozen=True)
class RunSpec:
    """One simulated ride and the estimator variants run over it.

    Attributes:
        key: the cell this run belongs to (e.g. ``"t4_B_10"``).
        group: seed group; ``run`` the run index inside it.
        vehicle: ``"quarter_car"`` or ``"lrv"``.
        road: ISO 8608 class letter, or ``"meadow_c"`` for the stand-in.
        soils: soil names along the path, equal stretches of ``stretch_s``.
        stretch_s: travel time on each soil (s).
        speed: constant travel speed (m/s).
        duration: simulated time (s).
        profile_rate: profile sampler rate (Hz).
        liftoff: unilateral tire contact in the truth.
        variants: estimator variants.
    """

    key: str
    group: int
    run: int
    vehicle: Literal["quarter_car", "lrv"]
    road: str
    soils: tuple[str, ...]
    stretch_s: float
    speed: float
    duration: float
    variants: tuple[Variant, ...]
    profile_rate: float = 1000.0
    liftoff: bool = False

    @property
    def cost(self) -> float:
        """Rough relative cost (simulated seconds × (1 + number of filters))."""
        return self.duration * (1.0 + len(self.variants))


@dataclass
class Trace:
    """One variant's estimate over one ride (arrays at the filter rate).

    Attributes:
        t: estimate times (s).
        err: relative error of k_s, 100 (k̂_s − k_s)/k_s (%).
        k_tot: k_tot estimate (N/m).
        k_tot_max: upper clamp of k_tot (N/m).
        recoveries: estimator recoveries from a non-finite posterior.
        finite: every estimate was finite.
        liftoff_fraction: fraction of samples with the tire off the ground.
        alarms: times (s) of the estimates that reported a soil change.
        change_stat_max: largest soil-change CUSUM statistic (σ) after the
            first 2 s (the start transient).
    """

    t: FloatArray
    err: FloatArray
    k_tot: FloatArray
    k_tot_max: float
    recoveries: int
    finite: bool
    liftoff_fraction: float = 0.0
    alarms: tuple[float, ...] = ()
    change_stat_max: float = 0.0


def run_seeds(group: int, run: int) -> tuple[int, int]:
    """(road seed, sensor-noise seed) of run ``run`` of seed group ``group``."""
    road, noise = np.random.SeedSequence([ROOT_SEED, group, run]).generate_state(2)
    return int(road), int(noise)


def _profile(road: str, seed: int) -> RoadProfile:
    if road == "meadow_c":
        return meadow_c_standin(seed)
    return iso8608_profile(road, seed)


def _soil_path(spec: RunSpec) -> SoilPath:
    soils = [soil_by_name(name) for name in spec.soils]
    return SoilPath([(i * spec.stretch_s * spec.speed, soil) for i, soil in enumerate(soils)])


def run_one(spec: RunSpec) -> tuple[RunSpec, dict[str, Trace]]:
    """Simulate one ride and run every variant over the same sensor data."""
    road_seed, noise_seed = run_seeds(spec.group, spec.run)
    path = _soil_path(spec)
    scenario = Scenario(
        profile=_profile(spec.road, road_seed),
        soil_path=path,
        speed=SpeedProfile.constant(spec.speed),
        profile_rate=spec.profile_rate,
        wheel_liftoff=spec.liftoff,
    )
    vehicle: QuarterCarVehicle | LRVVehicle = QuarterCarVehicle() if spec.vehicle == "quarter_car" else LRVVehicle()
    sim = simulate(vehicle, scenario, spec.duration, seed=noise_seed)
    t_acc = sim.t.tolist()
    body = sim.body_accel_z.tolist()
    wheel = sim.wheel_accel_z.tolist() if sim.wheel_accel_z is not None else [None] * len(t_acc)
    pt = sim.profile.t.tolist()
    ps = sim.profile.distance.tolist()
    ph = sim.profile.elevation.tolist()
    in_contact = np.asarray(sim.truth.in_contact, dtype=bool)
    liftoff_fraction = float(1.0 - in_contact.mean())
    traces: dict[str, Trace] = {}
    for variant in spec.variants:
        est = SoilStiffnessEstimator(variant.config(spec.vehicle))
        times: list[float] = []
        k_s: list[float] = []
        k_tot: list[float] = []
        alarms: list[float] = []
        stat_max = 0.0
        j = 0
        n_prof = len(pt)
        for i, t in enumerate(t_acc):
            stop = j
            while stop < n_prof and pt[stop] <= t + 1e-9:
                stop += 1
            while j < stop:  # each sample as add_profile_sample would take it, in bulk up to one that needs it
                j = est.add_profile_samples(pt, ps, ph, j, stop)
                if j < stop:
                    est.add_profile_sample(pt[j], ps[j], ph[j])
                    j += 1
            est.add_accelerations(t, body[i], wheel[i])
            for e in est.drain_estimates():
                times.append(e.t)
                k_s.append(e.k_s)
                k_tot.append(e.k_tot)
                if e.soil_change_detected:
                    alarms.append(e.t)
                if e.t > _START_S:
                    stat_max = max(stat_max, est.change_statistic)
        t_arr = np.asarray(times)
        truth = path.k_s_at(spec.speed * t_arr)
        ks_arr = np.asarray(k_s)
        finite = bool(np.all(np.isfinite(ks_arr)) and np.all(np.isfinite(k_tot)))
        traces[variant.label] = Trace(
            t=t_arr,
            err=100.0 * (ks_arr - truth) / truth,
            k_tot=np.asarray(k_tot),
            k_tot_max=float(est.model.ktot_bounds[1]),
            recoveries=int(est.counters.recoveries),
            finite=finite,
            liftoff_fraction=liftoff_fraction,
            alarms=tuple(alarms),
            change_stat_max=stat_max,
        )
    return spec, traces


# ---------------------------------------------------------------------------
# Metrics (definitions stated in the report)
# ---------------------------------------------------------------------------


def rmse(trace: Trace, t0: float, t1: float) -> float:
    """√(mean e²) of the relative k_s error (%) over estimates with t0 < t ≤ t1."""
    e = trace.err[_window(trace.t, t0, t1)]
    return float(np.sqrt(np.mean(e * e))) if e.size else math.inf


def mean_abs(trace: Trace, t0: float, t1: float) -> float:
    """Mean |e| of the relative k_s error (%) over estimates with t0 < t ≤ t1."""
    e = trace.err[_window(trace.t, t0, t1)]
    return float(np.mean(np.abs(e))) if e.size else math.inf


def settle_time(trace: Trace, t0: float, t1: float, threshold: float) -> tuple[float, bool]:
    """Time after ``t0`` from which |e| stays below ``threshold`` (%) up to ``t1``.

    Returns:
        (time (s), censored). ``censored`` when the error is still at or above
        the threshold at the last estimate of the window; the time is then the
        window length ``t1 − t0`` (a lower bound).
    """
    mask = _window(trace.t, t0, t1)
    t = trace.t[mask]
    bad = np.abs(trace.err[mask]) >= threshold
    if t.size == 0 or bad[-1]:
        return t1 - t0, True
    if not np.any(bad):
        return float(t[0] - t0), False
    last_bad = int(np.flatnonzero(bad)[-1])
    return float(t[last_bad + 1] - t0), False


# ---------------------------------------------------------------------------
# The plan: which rides, how many
# ---------------------------------------------------------------------------

SCKF = Variant("sckf", "sckf")
EKF = Variant("ekf", "ekf")
SCKF_PRINTED = Variant("sckf_printed", "sckf", noise_form="printed")
EKF_PRINTED = Variant("ekf_printed", "ekf", noise_form="printed")
EKF_PAPER_JAC = Variant("ekf_paper_jacobian", "ekf", jacobian="paper")
SCKF_LOG = Variant("sckf_log", "sckf", stiffness_state="log_k_s")
# The node's defaults (config/quarter_car.yaml): ln k_s state, soil-change detector and re-open.
SCKF_PROJECT = Variant("sckf_project", node_defaults=True)
LRV_RELATIVE = Variant("sckf", "sckf", relative_damper=True)
LRV_LITERAL = Variant("sckf_literal", "sckf", relative_damper=False)


@dataclass(frozen=True)
class Counts:
    """Monte Carlo run counts and durations of one invocation."""

    case1: int = 100
    rates: int = 50
    table4: int = 40
    lete: int = 100
    meadow: int = 20
    lrv: int = 40
    stretch_s: float = 10.0
    case1_duration: float = 12.0
    lete_duration: float = 12.0
    lrv_duration: float = 20.0
    nochange: int = 48
    nochange_lrv: int = 16
    nochange_duration: float = 60.0

    @classmethod
    def quick(cls) -> Counts:
        """Smoke run: one run of every cell, short rides."""
        return replace(cls().with_runs(1), stretch_s=3.0, lete_duration=6.0, lrv_duration=10.0, nochange_duration=6.0)

    def with_runs(self, n: int) -> Counts:
        return replace(self, case1=n, rates=n, table4=n, lete=n, meadow=n, lrv=n, nochange=n, nochange_lrv=n)


TABLE4_CELLS: tuple[tuple[str, float], ...] = (("B", 10.0), ("D", 10.0), ("F", 10.0), ("D", 2.0), ("D", 5.0))
PROFILE_RATES = (1000.0, 250.0, 100.0)


def _t4_key(road: str, speed: float) -> str:
    return f"t4_{road}_{speed:g}"


def build_plan(counts: Counts) -> list[RunSpec]:
    """Every ride of the reproduction: per cell, runs 0 … n − 1 of its seed group."""
    c, qc, gran = counts, "quarter_car", ("graneville_loam",)
    t1, t4, st, tl, tv = c.case1_duration, 3 * c.stretch_s, c.stretch_s, c.lete_duration, c.lrv_duration
    case1 = (SCKF, EKF, SCKF_PRINTED, EKF_PRINTED, SCKF_LOG)
    t4_variants = (SCKF, SCKF_PRINTED, SCKF_LOG, SCKF_PROJECT)
    lete = {False: (SCKF, EKF, EKF_PAPER_JAC, SCKF_PRINTED, EKF_PRINTED), True: (SCKF, EKF, EKF_PAPER_JAC)}
    # (runs, key, seed group, vehicle, road, soils, stretch (s), speed (m/s), duration (s), variants, options)
    cells: list[tuple[Any, ...]] = [
        (c.case1, "case1", _GROUP_GRANEVILLE, qc, "D", gran, t1, 10.0, t1, case1, {}),
        *(
            (c.rates, f"rate_{r:g}", _GROUP_GRANEVILLE, qc, "D", gran, t1, 10.0, t1, (SCKF, EKF), {"profile_rate": r})
            for r in PROFILE_RATES[1:]
        ),
        *(
            (c.table4, _t4_key(road, v), _GROUP_TABLE4, qc, road, _PATH_SOILS, st, v, t4, t4_variants, {})
            for road, v in TABLE4_CELLS
        ),
        *(
            (c.lete, key, _GROUP_LETE, qc, "F", ("lete_sand",), tl, 10.0, tl, lete[lift], {"liftoff": lift})
            for lift, key in ((False, "lete"), (True, "lete_liftoff"))
        ),
        (c.meadow, "meadow", _GROUP_MEADOW, qc, "meadow_c", _PATH_SOILS, st, 10.0, t4, (SCKF,), {}),
        (c.lrv, "lrv", _GROUP_LRV, "lrv", "G", ("lunar_regolith",), tv, 2.0, tv, (LRV_RELATIVE, LRV_LITERAL), {}),
    ]
    plan = [RunSpec(key, group, i, *ride, **options) for n, key, group, *ride, options in cells for i in range(n)]
    return plan + build_change_plan(counts)


GROUP_NOCHANGE = 6
"""Seed group of the quarter car's no-change runs."""
GROUP_NOCHANGE_LRV = 7
"""Seed group of the LRV's no-change runs."""
NOCHANGE_SOILS = ("lete_sand", "upland_sandy_loam", "graneville_loam")


def build_change_plan(counts: Counts) -> list[RunSpec]:
    """The no-change rides of case 2c (the Table 4 rides of case 2 carry the node-default variant)."""
    plan: list[RunSpec] = []
    duration = counts.nochange_duration
    for i in range(counts.nochange):
        soil = NOCHANGE_SOILS[i % len(NOCHANGE_SOILS)]
        road, speed = TABLE4_CELLS[(i // len(NOCHANGE_SOILS)) % len(TABLE4_CELLS)]
        plan.append(
            RunSpec(
                "nochange_qc",
                GROUP_NOCHANGE,
                i,
                "quarter_car",
                road,
                (soil,),
                duration,
                speed,
                duration,
                (SCKF_PROJECT,),
            )
        )
    lrv: tuple[Any, ...] = ("lrv", "G", ("lunar_regolith",), duration, 2.0, duration, (SCKF_PROJECT,))
    return plan + [RunSpec("nochange_lrv", GROUP_NOCHANGE_LRV, i, *lrv) for i in range(counts.nochange_lrv)]


Results = dict[str, list[dict[str, Trace]]]
"""Traces per cell key (``RunSpec.key``), one dict (variant label -> trace) per run, ordered by run."""

SectionWriter = Callable[[Report, Results, Counts], None]
"""A case's writer of the page: its section of ``rep`` from the results (nothing where it has no runs)."""


def writes_runs(key: str) -> Callable[[Callable[[Report, list[dict[str, Trace]], Counts], None]], SectionWriter]:
    """A case's section writer given the runs of the cell ``key``; it writes nothing where that cell has none."""

    def wrap(write: Callable[[Report, list[dict[str, Trace]], Counts], None]) -> SectionWriter:
        @functools.wraps(write)
        def writer(rep: Report, res: Results, counts: Counts) -> None:
            runs = res.get(key, [])
            if runs:
                write(rep, runs, counts)

        return writer

    return wrap


V = TypeVar("V")


def collect(plan: Sequence[RunSpec], rides: Sequence[tuple[RunSpec, dict[str, V]]]) -> dict[str, list[dict[str, V]]]:
    """The rides' traces (:func:`run_one` of each spec of ``plan``, in plan order) per cell key, in run order."""
    per_key: dict[str, dict[int, dict[str, V]]] = {}
    for spec, (_, traces) in zip(plan, rides, strict=True):
        per_key.setdefault(spec.key, {})[spec.run] = traces
    return {key: [runs[i] for i in sorted(runs)] for key, runs in per_key.items()}


def _settle_stats(runs: Sequence[dict[str, Trace]], label: str, t0: float, t1: float, thr: float) -> dict[str, float]:
    values, censored = [], 0
    for run in runs:
        value, cens = settle_time(run[label], t0, t1, thr)
        values.append(value)
        censored += int(cens)
    out = _stats(values)
    out["censored"] = float(censored)
    return out


def _ms(s: dict[str, float]) -> str:
    return f"{_fmt(s['mean'])} ± {_fmt(s['std'])}"
