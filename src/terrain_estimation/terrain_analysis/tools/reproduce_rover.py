"""Reproduce the rocker-bogie terrain-response results of Setterfield & Ellery (MODELS.md Part C, D.3).

``python -m terrain_analysis.tools.reproduce_rover [--seeds N] [--out docs/results] [--jobs 2] [--quick]``

Every number the report shows is computed here, when the command runs, by the
project's own truth plant (:func:`vehicle_sim.plants.rover.simulate_rover`:
constrained multibody dynamics of one side of Kapvik on Fig. 10's terrains 1–6,
:data:`~vehicle_sim.plants.rover.TERRAIN_NUMBERS`, Table IV sensor noise) and
its own estimators (:class:`~terrain_estimation.estimators.rover.RoverTerrainEstimator`
with ``load_cell_axes=2`` = Estimators 1 + 2 and ``load_cell_axes=1`` =
Estimators 1 + 3, fed the *same* sensor samples; the plant records both
load-cell axes, Estimator 3 ignores the second). The paper's numbers appear
only as the comparison column; the truth plant, its noise and the seeds are
never tuned towards the paper.

Cases (as in the report):

1. Table V: RMS errors of slip, normal load W, resistive torque τ_R and
   drawbar pull DP per wheel (1 rear, 2 middle, 3 front) and terrain.
2. Table VI: 2nd-order fits DP(W, i), τ_R(W, i) to the estimates of terrains
   1–5 (:class:`~terrain_estimation.estimators.rover.TerrainResponseAccumulator`:
   one sample per wheel per 2 s, curvature gate κ < 1/l_w), beside the "local
   model" (2nd-order fit to a 100×100 sample of the true global model over
   the traversed region).
3. Table VII: RMS of the fitted models against the true global model over the
   traversed region (100×100 grid); inside and outside the data's hull.
4. Error against terrain curvature and the ż0^R ≈ 0 assumption (section V-B).
5. Speed: simulator (full Wong–Reece and surrogate) and estimators as
   multiples of real time.

Seeds: sensor-noise run ``i`` of Fig. 10 terrain ``n`` uses the seed
``SeedSequence([ROOT_SEED, n, i]).generate_state(1)[0]``. The truth plant is
deterministic (its seed drives only the sensor noise), so each terrain is
simulated once, with the seed of run 0, and the sensor readings of runs
1…N−1 are drawn from the plant's own noise streams (:func:`renoise`, the
plant's ``SeedSequence(seed).spawn(7)`` streams and Table IV σ on the truth's
noise-free channels). The report checks, per terrain, that :func:`renoise`
reproduces the plant's own readings of run 0 bit for bit; where it does not,
every run is simulated in full instead.

The pieces: :mod:`~terrain_analysis.tools.rover_plan` (variants, terrains,
seeds, run counts, the paper's tables), :mod:`~terrain_analysis.tools.rover_runs`
(simulate, re-noise, estimate, pair with the truth),
:mod:`~terrain_analysis.tools.rover_fits` (the 2nd-order models),
the sections :mod:`~terrain_analysis.tools.rover_table5`,
:mod:`~terrain_analysis.tools.rover_models`, :mod:`~terrain_analysis.tools.rover_curvature`,
:mod:`~terrain_analysis.tools.rover_speed`, :mod:`~terrain_analysis.tools.rover_consistency`,
and the page, :mod:`~terrain_analysis.tools.rover_report`. The jobs run on the
shared runner (:class:`terrain_analysis.experiment.Runner`: ``--jobs 1`` in this
process, more on a local Dask cluster, or ``--scheduler``), the page is written
by :func:`terrain_analysis.reporting.write_page`.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from terrain_analysis.experiment import Runner, print_claims
from terrain_analysis.reporting import Provenance, Report, reproduction_arguments
from terrain_analysis.tools.rover_consistency import section_consistency
from terrain_analysis.tools.rover_curvature import section_curvature
from terrain_analysis.tools.rover_fits import (
    convex_hull,
    inside_polygon,
    region_grid,
)
from terrain_analysis.tools.rover_models import section_surrogate, section_tables67
from terrain_analysis.tools.rover_plan import (
    ALL_VARIANTS,
    PAPER_CHOICES,
    PAPER_TABLE5,
    PAPER_TABLE6,
    PAPER_TABLE7,
    PAPER_VARIANTS,
    QUANTITIES,
    ROOT_SEED,
    VARIANTS,
    Counts,
    Task,
    build_plan,
    paper_choices,
    run_seed,
    variant_config,
)
from terrain_analysis.tools.rover_report import RoverReport, write_report
from terrain_analysis.tools.rover_runs import (
    Series,
    SpeedData,
    TerrainData,
    estimate_run,
    execute,
    renoise,
    stamp_indices,
    wheel_rms,
)
from terrain_analysis.tools.rover_speed import section_speed
from terrain_analysis.tools.rover_table5 import section_table5, section_timeseries
from terrain_estimation.cli import cli_main
from vehicle_sim.terrain.terramechanics_surrogate import terramechanics_surrogate

__all__ = [
    "ROOT_SEED",
    "VARIANTS",
    "PAPER_VARIANTS",
    "PAPER_CHOICES",
    "paper_choices",
    "variant_config",
    "QUANTITIES",
    "PAPER_TABLE5",
    "PAPER_TABLE6",
    "PAPER_TABLE7",
    "Counts",
    "Task",
    "Series",
    "TerrainData",
    "SpeedData",
    "run_seed",
    "build_plan",
    "renoise",
    "estimate_run",
    "stamp_indices",
    "wheel_rms",
    "region_grid",
    "convex_hull",
    "inside_polygon",
    "main",
]


@cli_main("reproduce-rover")
def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args, argv_list = reproduction_arguments(
        "python -m terrain_analysis.tools.reproduce_rover",
        (__doc__ or "").splitlines()[0],
        argv,
        runs_flag="--seeds",
        runs_help="sensor-noise runs per terrain (default 4)",
        quick_help="smoke run: 4 s per terrain, 2 runs (< 1 min)",
        extra=(
            (
                "--terramechanics",
                {
                    "choices": ("surrogate", "wong_reece"),
                    "default": "surrogate",
                    "help": "soil model of the truth runs (default: surrogate, as the paper)",
                },
            ),
        ),
    )
    counts = Counts.quick() if args.quick else Counts()
    if args.seeds is not None:
        counts = counts.with_seeds(args.seeds)
    rr = RoverReport(Report.for_page(args.out, "rover"))
    plan = build_plan(counts, args.terramechanics)
    print(
        f"reproduce_rover: {len(plan)} jobs ({counts.seeds} noise runs per terrain) on {args.jobs} process(es)",
        file=sys.stderr,
        flush=True,
    )
    with Runner(args.jobs, scheduler=args.scheduler, what="jobs (6 terrains, 2 simulator-speed runs)") as runner:
        res = execute(plan, counts, runner)
        surrogate = terramechanics_surrogate()
        section_surrogate(rr, surrogate)
        section_table5(rr, res, counts)
        section_timeseries(rr, res, counts)
        section_tables67(rr, res, counts, surrogate)
        section_curvature(rr, res, counts)
        section_speed(rr, res, counts)
        section_consistency(rr, res, ALL_VARIANTS, VARIANTS)
        prov = Provenance.of("terrain_analysis.tools.reproduce_rover", argv_list, runner, quick=args.quick)
    print_claims(rr.rep, write_report(rr, res, counts, prov, args.terramechanics), prov)
    return 0


if __name__ == "__main__":
    sys.exit(main())
