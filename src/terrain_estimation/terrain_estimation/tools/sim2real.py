"""``terrain-sim2real BAG --vehicle V [-o DIR]``: where does the bag disagree with the simulator, and why?

Replays the vehicle's nominal model on the bag's measured inputs and reports
where the residual exceeds the noise budget (per channel, octave band, time
window and operating regime; for the quarter car and LRV also the estimator's
NIS). Then adds each effect of the catalogue in turn, fits its parameters on
a training part of the bag, scores it on the held-out part, ranks the effects
(penalised for the parameters they add), tries pairs when no single effect
explains the gap, and gives the held-out shrinkage of the gap with a bootstrap
interval and a verdict. Reads only the bag and the vehicle's config.

The verdict goes to stdout; progress to stderr; Markdown, JSON and figures to
DIR. Exit status: 0 no significant gap, 1 a gap (explained or not), 2 error.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

from terrain_estimation.bag import BagError
from terrain_estimation.params import ParameterError
from terrain_estimation.sim2real.diagnose import BUILDERS, diagnose
from terrain_estimation.sim2real.where import Sim2RealError

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="terrain-sim2real", description=__doc__.splitlines()[0])
    parser.add_argument("bag", help="input bag directory (mcap or sqlite3)")
    parser.add_argument("--vehicle", required=True, choices=tuple(BUILDERS), help="vehicle model")
    parser.add_argument("-o", "--output", help="directory for diagnosis.md, diagnosis.json and the figures")
    parser.add_argument("--namespace", help="namespace the bag was recorded under (default: the vehicle's)")
    parser.add_argument("--config", help="parameter file (default: config/<vehicle>.yaml)")
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    args = parser.parse_args(argv)
    started = time.monotonic()

    def progress(text: str) -> None:
        if not args.quiet:
            print(f"sim2real [{time.monotonic() - started:5.1f} s]: {text}", file=sys.stderr, flush=True)

    try:
        result = diagnose(args.bag, args.vehicle, namespace=args.namespace, config=args.config, progress=progress)
        if args.output:
            from terrain_estimation.sim2real.report import write_diagnosis

            paths = write_diagnosis(result, args.output, figures=not args.no_figures)
            progress(f"wrote {', '.join(str(p) for p in paths)}")
    except (BagError, ParameterError, Sim2RealError, ValueError) as exc:
        print(f"terrain-sim2real: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("terrain-sim2real: interrupted", file=sys.stderr)
        return 130
    progress(f"done in {time.monotonic() - started:.1f} s")
    print(f"verdict: {result.verdict}")
    for gap in result.where.gaps[:12]:
        print(f"  - {gap}")
    if len(result.where.gaps) > 12:
        print(f"  - … {len(result.where.gaps) - 12} more in the report")
    return 0 if result.attribution.kind == "no_gap" else 1


if __name__ == "__main__":
    sys.exit(main())
