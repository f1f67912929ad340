"""Assemble ``docs/results/sim2real.md`` from the generated sections (issue 6).

The sections are written by their own commands (each a make target), so that
a long run never has to be repeated to refresh another part:

* ``make validate-sim2real`` → ``docs/results/sim2real/validation.md``
  (:mod:`terrain_analysis.tools.validate_sim2real`), and
  ``make validate-sim2real-seed2027`` → ``docs/results/sim2real/validation_seed2027.md``
  (the same on a second suite);
* ``make sim2real-real-data`` → ``docs/results/sim2real/cmu/single_wheel.md``
  (:mod:`terrain_analysis.sim2real.single_wheel`) and
  ``docs/results/sim2real/husky/husky.md`` (:mod:`terrain_analysis.sim2real.husky`).

This tool only concatenates them under a fixed introduction (how the
diagnosis works and how to read the numbers); a missing section is named as
missing, never filled in.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from terrain_estimation.cli import cli_main

__all__ = ["SECTIONS", "assemble", "main"]

SECTIONS = (
    ("validation.md", "make validate-sim2real"),
    ("validation_seed2027.md", "make validate-sim2real-seed2027"),
    ("cmu/single_wheel.md", "make sim2real-real-data"),
    ("husky/husky.md", "make sim2real-real-data"),
)

INTRO = """# Sim-to-real gap diagnosis (issue 6)

`terrain-sim2real BAG --vehicle V -o DIR` reads a contract bag (and the
vehicle's config, nothing else) and answers three questions:

1. **Where** the nominal model and the bag disagree: the nominal model is
   replayed on the bag's measured inputs (quarter car / LRV: the measured road
   profile; skid steer: the measured wheel speeds; rover: the measured
   configuration, wheel rates and torques), with the parameters a real bag
   cannot give (the *nuisance*, e.g. the soil stiffness) fitted. The residual
   is tested against the noise budget per channel (bias, power, octave bands,
   delay, gain), per time window and per operating regime; for the quarter car
   and LRV the estimator's NIS is added.
2. **Which effect** of the catalogue (`vehicle_sim.effects.CATALOGUE`)
   explains it: each effect is added in turn, its parameters fitted on two
   thirds of the bag (interleaved 1 s blocks) and scored on the held-out third
   (χ² + p ln n, p the parameters it adds); when the best single effect does
   not bring the residual to the noise, pairs are tried (forward selection).
   An effect counts when the change it predicts on the held-out part is found
   there at 0.99 (a one-sided matched-filter test: the projection of the
   nominal's held-out residual on that change, its variance from batch means
   inside the held-out blocks, never below the noise budget's, against
   Student's t) and it lowers the held-out χ² by at least 2 % and the
   penalised score.
3. **How far the gap shrinks**: gap = mean normalised residual power above the
   noise, shrinkage = 1 − gap(with effect) / gap(nominal) on the held-out part,
   with a block-bootstrap interval.

The verdict is "no significant gap", "explained by X (shrinks the gap by N %)"
or "not explained by the catalogue (best candidate X leaves N % unexplained)"
(with the reason when X's held-out improvement is not significant, or when
X's held-out residual still fails a noise test). A significant runner-up the
held-out data cannot tell from X is named as indistinguishable on that bag.
Samples outside a replay model's domain (a rover sliding backward, beyond
the quasi-static replay) are left out of every fit, score and test, with a
note in the report. The engine is generic (`terrain_analysis.sim2real.attribution`); each
vehicle provides a replay model (`terrain_analysis.sim2real.<vehicle>`).
"""


def assemble(root: str | Path = "docs/results") -> str:
    """The text of ``sim2real.md`` from the sections under ``root/sim2real``."""
    base = Path(root) / "sim2real"
    parts = [INTRO]
    for rel, command in SECTIONS:
        path = base / rel
        if path.exists():
            text = path.read_text(encoding="utf-8").rstrip() + "\n"
            # Figures and files of a section are relative to its own folder.
            prefix = str(Path("sim2real") / Path(rel).parent).replace("\\", "/").rstrip("/.")
            text = text.replace("](./", f"]({prefix}/").replace('src="./', f'src="{prefix}/')
            parts.append(text)
        else:
            parts.append(f"## (missing) `{rel}`\n\nNot generated yet: run `{command}`.\n")
    return "\n".join(parts)


@cli_main("sim2real-results")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", default="docs/results", help="results folder (default docs/results)")
    args = parser.parse_args(argv)
    out = Path(args.root) / "sim2real.md"
    out.write_text(assemble(args.root), encoding="utf-8")
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
