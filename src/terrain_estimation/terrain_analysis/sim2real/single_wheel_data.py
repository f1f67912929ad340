"""The CMU single-wheel rig's trials: the trial file and the noise of its repeated trials (single-wheel check)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.where import Sim2RealError

__all__ = ["DATA_FILE", "RigTrials", "load_rig_trials", "pooled_replicate_std"]

FloatArray = NDArray[np.float64]

DATA_FILE = "all_smooth_data.mat"


@dataclass(frozen=True)
class RigTrials:
    """The β = 0 trials, ordered by slip then trial number.

    Attributes:
        slip: i (–).
        load: W = −avg_Fz (N).
        drawbar_pull: DP = −avg_Fy (N).
        drawbar_pull_ripple: std_Fy, within-trial fluctuation (N).
        sinkage: z = −avg_Z (mm, positive down).
        sinkage_ripple: std_Z (mm).
        trial: trial_num of the file.
        group: index of the commanded-slip group (repeated trials share it).
        total_trials: trials in the file (all β).
        betas: the distinct β of the file (deg).
        source: the file read.
    """

    slip: FloatArray
    load: FloatArray
    drawbar_pull: FloatArray
    drawbar_pull_ripple: FloatArray
    sinkage: FloatArray
    sinkage_ripple: FloatArray
    trial: FloatArray
    group: NDArray[np.int_]
    total_trials: int
    betas: tuple[float, ...]
    source: str

    @property
    def size(self) -> int:
        return int(self.slip.size)

    def subset(self, keep: NDArray[np.bool_]) -> RigTrials:
        """The trials where ``keep`` is True (groups renumbered)."""
        keep = np.asarray(keep, dtype=bool)
        if keep.shape != self.slip.shape or not keep.any():
            raise ValueError(f"subset mask must select some of the {self.size} trials")
        rows = ("slip", "load", "drawbar_pull", "drawbar_pull_ripple", "sinkage", "sinkage_ripple", "trial")
        return dataclasses.replace(
            self,
            **{name: getattr(self, name)[keep] for name in rows},
            group=np.unique(self.group[keep], return_inverse=True)[1].astype(int),
        )


_FIELDS = ("slip", "beta", "avg_Fy", "std_Fy", "avg_Fz", "avg_Z", "std_Z")


def _slip_groups(slip: FloatArray, tolerance: float = 0.02) -> NDArray[np.int_]:
    """Group index of each (sorted) slip: a new group where the gap exceeds ``tolerance``."""
    if slip.size == 0:
        return np.zeros(0, dtype=int)
    return np.concatenate([[0], np.cumsum(np.diff(slip) > tolerance)]).astype(int)


def load_rig_trials(folder: str | Path, file: str | None = None) -> RigTrials:
    """Read a trial file of the rig's layout and keep the β = 0 trials.

    Args:
        folder: A folder holding the file, or the file itself.
        file: The file's name in ``folder`` (default :data:`DATA_FILE`, the
            smooth wheel; any file with the same layout, e.g. another wheel's
            ``all_results``, is read the same way).

    Raises:
        Sim2RealError: missing file or field, or a value that is not finite or
            out of its physical range (names the file, trial, field and value).
    """
    import scipy.io

    given = Path(folder)
    path = given if given.is_file() and file is None else given / (file or DATA_FILE)
    if not path.is_file():
        raise Sim2RealError(f"{path}: no such file (a CMU single-wheel trial file, e.g. {DATA_FILE})")
    try:
        mat = scipy.io.loadmat(str(path), squeeze_me=True, struct_as_record=False)
    except Exception as exc:  # scipy raises several types for a damaged file
        raise Sim2RealError(f"{path}: not a readable MATLAB file ({exc})") from exc
    if "all_results" not in mat:
        raise Sim2RealError(
            f"{path}: no variable 'all_results' (has {sorted(k for k in mat if not k.startswith('_'))})"
        )
    trials = np.atleast_1d(mat["all_results"])
    rows = []
    for k, t in enumerate(trials):
        values = {}
        for name in _FIELDS:
            if not hasattr(t, name):
                raise Sim2RealError(f"{path}: trial {k} has no field {name!r}")
            try:
                v = float(getattr(t, name))
            except (TypeError, ValueError):
                raise Sim2RealError(f"{path}: trial {k} field {name!r} is not a number: {getattr(t, name)!r}") from None
            if not math.isfinite(v):
                raise Sim2RealError(f"{path}: trial {k} field {name!r} = {v} is not finite")
            values[name] = v
        if not -1.0 <= values["slip"] <= 1.0:
            raise Sim2RealError(f"{path}: trial {k} field 'slip' = {values['slip']} outside [-1, 1]")
        if values["avg_Fz"] >= 0.0:
            raise Sim2RealError(f"{path}: trial {k} field 'avg_Fz' = {values['avg_Fz']} N: the load must be < 0 (down)")
        values["trial"] = float(getattr(t, "trial_num", k))
        rows.append(values)
    betas = tuple(sorted({r["beta"] for r in rows}))
    planar = [r for r in rows if abs(r["beta"]) < 0.5]
    if len(planar) < 6:
        raise Sim2RealError(f"{path}: only {len(planar)} trials at beta = 0 (field 'beta'); need at least 6")
    planar.sort(key=lambda r: (r["slip"], r["trial"]))
    slip = np.array([r["slip"] for r in planar])
    return RigTrials(
        slip=slip,
        load=-np.array([r["avg_Fz"] for r in planar]),
        drawbar_pull=-np.array([r["avg_Fy"] for r in planar]),
        drawbar_pull_ripple=np.array([r["std_Fy"] for r in planar]),
        sinkage=-np.array([r["avg_Z"] for r in planar]),
        sinkage_ripple=np.array([r["std_Z"] for r in planar]),
        trial=np.array([r["trial"] for r in planar]),
        group=_slip_groups(slip),
        total_trials=len(rows),
        betas=betas,
        source=str(path),
    )


def pooled_replicate_std(values: FloatArray, group: NDArray[np.int_]) -> tuple[float, int]:
    """Pooled standard deviation of repeated trials about their group means, and its degrees of freedom."""
    resid = np.zeros_like(values)
    groups = np.unique(group)
    for g in groups:
        sel = group == g
        resid[sel] = values[sel] - values[sel].mean()
    dof = values.size - groups.size
    if dof < 1:
        raise Sim2RealError("no repeated trials: the noise budget needs at least two trials at one slip")
    return float(math.sqrt(float(np.sum(resid**2)) / dof)), int(dof)
