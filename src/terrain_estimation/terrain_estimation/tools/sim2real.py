"""``terrain-sim2real BAG --vehicle V [-o DIR]``: where does the bag disagree with the nominal simulator?

Replays the nominal plant open loop on the bag's measured profile and speed
(quarter car and LRV) and reports, per accelerometer channel, frequency band,
time window and speed bin, where the residual exceeds what the sensor noise
explains, plus the estimator's NIS. Reads only the bag and the vehicle's
config. The verdict goes to stdout; Markdown, JSON and figures to DIR.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

from terrain_estimation.bag import BagError
from terrain_estimation.params import ParameterError
from terrain_estimation.sim2real.where import SUPPORTED_VEHICLES, Sim2RealError, diagnose_where

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="terrain-sim2real", description=__doc__.splitlines()[0])
    parser.add_argument("bag", help="input bag directory (mcap or sqlite3)")
    parser.add_argument("--vehicle", required=True, choices=SUPPORTED_VEHICLES, help="vehicle model")
    parser.add_argument("-o", "--output", help="directory for where.md, where.json and the figures")
    parser.add_argument("--namespace", help="namespace the bag was recorded under (default: the vehicle's)")
    parser.add_argument("--config", help="parameter file (default: config/<vehicle>.yaml)")
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    args = parser.parse_args(argv)
    started = time.monotonic()
    try:
        report = diagnose_where(args.bag, args.vehicle, args.namespace, args.config, progress=True)
        if args.output:
            from terrain_estimation.sim2real.report import write_report

            paths = write_report(report, args.output, figures=not args.no_figures)
            print(f"sim2real: wrote {', '.join(str(p) for p in paths)}", file=sys.stderr)
    except (BagError, ParameterError, Sim2RealError, ValueError) as exc:
        print(f"terrain-sim2real: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("terrain-sim2real: interrupted", file=sys.stderr)
        return 130
    print(f"sim2real: done in {time.monotonic() - started:.1f} s", file=sys.stderr)
    print(f"verdict: {'no significant gap' if not report.gaps else 'gap'}")
    for gap in report.gaps:
        print(f"  - {gap}")
    return 1 if report.gaps else 0


if __name__ == "__main__":
    sys.exit(main())
