"""``terrain-sim2real BAG --vehicle V [-o DIR]``: where does the bag disagree with the simulator, and why?

Checks the bag's inputs first, with the estimator's own input checks and
plausibility bounds (terrain_analysis.sim2real.inputs): rejected messages
are dropped and counted, and a bag with time gaps is split into segments of
which one is analysed (the longest, or --segment N). Then replays the
vehicle's nominal model on the bag's measured inputs and reports where the
residual exceeds the noise budget (per channel, octave band, time window and
operating regime; for the quarter car and LRV also the estimator's NIS).
Then adds each effect of the catalogue in turn, fits its parameters on a
training part of the bag, scores it on the held-out part, ranks the effects
(penalised for the parameters they add), tries pairs when no single effect
explains the gap, and gives the held-out shrinkage of the gap with a
bootstrap interval and a verdict. Reads only the bag and the vehicle's config.

The input checks and the verdict go to stdout; progress to stderr; Markdown,
JSON and figures to DIR. Exit status (terrain_estimation.cli): 0 no
significant gap, 1 a gap (explained or not), 2 the input cannot be used (a
missing topic, a topic of another type, nothing usable left after the
checks), 3 internal error.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

from terrain_analysis.sim2real.diagnose import BUILDERS, diagnose
from terrain_analysis.sim2real.inputs import GAP_MIN_S
from terrain_estimation.cli import EXIT_FINDING, EXIT_OK, run_cli
from terrain_estimation.outputs import check_output_dir, prepare_output_dir

__all__ = ["main"]

PROG = "terrain-sim2real"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("bag", help="input bag directory (mcap or sqlite3)")
    parser.add_argument("--vehicle", required=True, choices=tuple(BUILDERS), help="vehicle model")
    parser.add_argument("-o", "--output", help="directory for diagnosis.md, diagnosis.json and the figures")
    parser.add_argument("--namespace", help="namespace the bag was recorded under (default: the vehicle's)")
    parser.add_argument("--config", help="parameter file (default: config/<vehicle>.yaml)")
    parser.add_argument(
        "--segment", type=int, help="analyse this segment (1-based) of a bag with time gaps (default: the longest)"
    )
    parser.add_argument(
        "--max-gap",
        type=float,
        default=GAP_MIN_S,
        metavar="S",
        help=f"shortest stamp gap (s) that splits the bag, if above 10 median periods (default {GAP_MIN_S:g})",
    )
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    parser.add_argument(
        "--overwrite", action="store_true", help="write into an existing -o directory not made by a project tool"
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    args = parser.parse_args(argv)
    started = time.monotonic()

    def progress(text: str) -> None:
        if not args.quiet:
            print(f"sim2real [{time.monotonic() - started:5.1f} s]: {text}", file=sys.stderr, flush=True)

    def body() -> int:
        inputs = [args.bag, *([args.config] if args.config else [])]
        if args.output:  # refused before the diagnosis, not after it; created only once there is one to write
            check_output_dir(args.output, overwrite=args.overwrite, inputs=inputs)
        result = diagnose(
            args.bag,
            args.vehicle,
            namespace=args.namespace,
            config=args.config,
            progress=progress,
            segment=args.segment,
            min_gap=args.max_gap,
        )
        if args.output:
            from terrain_analysis.sim2real.report import write_diagnosis

            prepare_output_dir(args.output, overwrite=args.overwrite, inputs=inputs, tool=PROG)
            paths = write_diagnosis(result, args.output, figures=not args.no_figures)
            progress(f"wrote {', '.join(str(p) for p in paths)}")
        progress(f"done in {time.monotonic() - started:.1f} s")
        if result.inputs is not None:
            for line in result.inputs.lines():
                print(line)
        print(f"verdict: {result.verdict}")
        for gap in result.where.gaps[:12]:
            print(f"  - {gap}")
        if len(result.where.gaps) > 12:
            print(f"  - … {len(result.where.gaps) - 12} more in the report")
        return EXIT_OK if result.attribution.kind == "no_gap" else EXIT_FINDING

    return run_cli(PROG, body)


if __name__ == "__main__":
    sys.exit(main())
