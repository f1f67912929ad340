"""How the rover replay's wheels sink: the depth s_j(t) of each wheel centre below the undisturbed surface.

A wheel on deformable soil rides below the surface by its sinkage, and a wheel
whose sinkage changes moves at ṡ_j across the surface it rolls on, which the
replay's wheel-velocity relation (relation 3 of :mod:`terrain_analysis.sim2real.rover`)
must add: its centre moves at v_t along the terrain tangent and at −ṡ cos γ along
the terrain normal (the sinkage is vertical; v_t, from the slip, is the speed along
the tangent). The ż0^R differences carry the differences of the wheels' ṡ (≈ 2e-4 m
per N of load change on [RB] Table II's soil, so a wheel whose load changes by
1 N/s sinks at 2e-4 m/s, ≈ 7 σ of the channels' noise).

The steady depth z*(W, i) is the replay's soil's own Wong–Reece solution
(:meth:`~terrain_analysis.sim2real.rover_soil._SoilModel.depth`), at the loads and
slips the replay infers. The depth follows it as a plastic soil does:

* a rising load presses the soil under the rim within the config's loading time
  τ (simulator section ``sinkage_loading_time``): a critically damped lag
  s̈ = ω² (z* − s) − 2ω ṡ with ω = 1/τ;
* a falling load leaves a compacted rut that does not spring back: the rim climbs
  onto fresh soil over about one contact length l = r_e sin θ0 of travel, the same
  lag with ω = |v_t| / l (at most 1/τ), l of the deeper of s and z* (≥ 1 mm).

z* is held over each sample interval and the lag solved in closed form within it,
so s and ṡ are continuous.

The bag does not say how deep the wheels sat when it started (a rut left by a
heavier load before it would keep them deeper), and its first samples may not be
the wheels' state (streams that start late, a delayed stream's first values, the
edge of a smoothing window). The sinkage is held at rest over the first
:data:`START_WINDOW` (inside the replay's 3 s warm-up) at z* of the window's end,
and the lag runs from there. To it adds the rut the wheel started in, d_j ≥ 0
below that depth: a segment that starts mid-drive (a bag cut at a time gap)
finds each wheel where its earlier loads left it, deeper than z* if they were
heavier, and the wheel climbs out at the unloading rate, over about a contact
length of travel (a few seconds at a few cm/s); the rut decays by the same lag
towards 0, a state of its own so that (s, ṡ) are smooth and nearly linear in d_j
(the offset as the lag's own start had a kink at d_j = 0, its switch between the
loading and the unloading rate, where the fit stopped at 0).
The bag cannot say how deep, so the replay fits d_j as a nuisance
(:data:`START_OFFSET`, in mm, bounded at 0 with a Gaussian prior of σ
:data:`START_OFFSET_PRIOR`: a half-normal); a shallower start would be pressed to
z* within τ, inside the warm-up, so d_j is not negative. On the shipped
rover_terrain_2's second half the front wheel started 0.07 mm below the replay's
z* (the replay of the whole bag at that instant), which decays over ≈ 4 s and
biased ``vz_front_middle`` by 4e-6 m/s after the warm-up, read as a soil change.

A start at z* too deep would decay at the slow unloading rate over many seconds:
started at z* of the first sample, the front wheel of a rolling-terrain run (its
first load 1 N off) had ṡ off by 5e-6 m/s on average
over 20 s (0.2 σ of the ż0^R channels), and a run with delayed sensors (zero loads
over the first 60 ms) sank 1.5 mm too deep; started at the window's end, the
replay of the plant's own z* repeats its sinkage to 1e-12 m after the warm-up.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.model import FitParameter
from terrain_analysis.sim2real.rover_bag import WHEELS
from terrain_estimation.jit import compiled

FloatArray = NDArray[np.float64]

__all__ = ["START_OFFSET", "START_OFFSET_PRIOR", "sinkage_motion", "start_offsets"]

_MIN_CONTACT = 1.0e-3  # m, shortest contact length of the unloading rate
START_WINDOW = 1.0
"""s, the start of the bag over which the sinkage is held at z* of its end (module docstring)."""
START_OFFSET_PRIOR = 0.5
"""mm, σ of the (half-normal) prior of a wheel's start rut: that of a load ≈ 2.5 N heavier (z* changes by
≈ 0.2 mm per N on [RB] Table II's soil); the fit is bounded at 6 σ."""

#: The replay's nuisance parameters of the sinkage's unknown start, one per wheel (module docstring), in mm.
START_OFFSET: dict[str, FitParameter] = {
    f"sinkage_start_{w}": FitParameter(
        f"sinkage_start_{w}", "mm", 0.0, (0.0, 6.0 * START_OFFSET_PRIOR), 0.1, prior_std=START_OFFSET_PRIOR
    )
    for w in WHEELS
}


def start_offsets(nuisance: Mapping[str, float]) -> FloatArray:
    """The wheels' start ruts d_j (m), in :data:`WHEELS` order, of the nuisance values (absent: 0)."""
    return np.array([1e-3 * float(nuisance.get(f"sinkage_start_{w}", 0.0)) for w in WHEELS])


def sinkage_motion(
    t: FloatArray,
    target: FloatArray,
    speed: FloatArray,
    *,
    loading_time: float,
    radius: float,
    grouser_height: float = 0.0,
    start_offset: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """(s, ṡ) (m, m/s), (N, W) each, of wheels whose steady depth is ``target`` (N, W) at the times ``t`` (N,).

    ``speed``: each wheel centre's speed along the terrain (m/s), (N, W); ``radius``: the
    wheel's radius r_w (m); ``grouser_height``: h_g (m), the contact cylinder being r_w + h_g
    (module docstring); ``start_offset``: each wheel's rut d_j below z* at the end of the start
    window (m), (W,) (default none).
    """
    n, wheels = target.shape
    s = np.zeros((n, wheels))
    rate = np.zeros((n, wheels))
    if n == 0:
        return s, rate
    steps = np.diff(np.asarray(t, dtype=np.float64))
    first = min(int(np.searchsorted(t, t[0] + START_WINDOW)), n - 1)
    depth_s, depth_rate = np.zeros(n), np.zeros(n)
    for j in range(wheels):
        # The rut below z* the wheel started in, climbing out at the unloading rate.
        rut = 0.0 if start_offset is None else float(start_offset[j])
        _wheel_sinkage(
            np.ascontiguousarray(target[:, j], dtype=np.float64),
            np.abs(np.asarray(speed[:, j], dtype=np.float64)),
            steps,
            first,
            rut,
            1.0 / loading_time,
            radius + grouser_height,
            float(grouser_height),
            depth_s,
            depth_rate,
        )
        s[:, j] = depth_s
        rate[:, j] = depth_rate
    return s, rate


@compiled
def _wheel_sinkage(
    z: FloatArray,
    v: FloatArray,
    steps: FloatArray,
    first: int,
    rut: float,
    loading: float,
    r_e: float,
    grouser_height: float,
    out_s: FloatArray,
    out_rate: FloatArray,
) -> None:  # pragma: no cover  (compiled; the tests call it through sinkage_motion)
    """One wheel's (s, ṡ) into ``out_s``, ``out_rate`` (module docstring): held at z[first] over the start
    window, then the lag towards z held over each sample interval; the rut decays at the unloading rate.

    Compiled (it ran ≈ 70 % of a rover diagnosis in Python: one call per replay, 3 wheels × every sample).
    ``min``/``max`` are written out as Python's (the first argument unless the second is strictly
    smaller/larger), so the values are those of the former Python loop, bit for bit.
    """
    n = z.shape[0]
    depth = z[first]
    velocity = 0.0
    rut_rate = 0.0
    for k in range(first + 1):
        out_s[k] = depth + rut
        out_rate[k] = velocity
    for k in range(first, n - 1):
        dt = steps[k]
        goal = z[k]
        unloading = 0.0
        if goal < depth or rut > 0.0:
            deepest = goal if goal > depth else depth
            ratio = (deepest + rut + grouser_height) / r_e
            cos0 = 1.0 - (1.0 if 1.0 < ratio else ratio)
            chord = 1.0 - cos0 * cos0
            contact = r_e * math.sqrt(0.0 if 0.0 > chord else chord)
            if _MIN_CONTACT > contact:
                contact = _MIN_CONTACT
            unloading = v[k] / contact
            if loading < unloading:
                unloading = loading
        depth, velocity = _lag(depth, velocity, goal, loading if goal >= depth else unloading, dt)
        if rut > 0.0:
            rut, rut_rate = _lag(rut, rut_rate, 0.0, unloading, dt)
        out_s[k + 1] = depth + rut
        out_rate[k + 1] = velocity + rut_rate


@compiled
def _lag(
    depth: float, velocity: float, goal: float, omega: float, dt: float
) -> tuple[float, float]:  # pragma: no cover  (compiled)
    """(s, ṡ) after ``dt`` of the critically damped lag at ``omega`` towards ``goal`` (held over ``dt``)."""
    if not omega > 0.0:
        return depth + velocity * dt, velocity
    # e = s − z* = (A + B τ) e^(−ωτ), A = e0, B = ė0 + ω e0.
    a = depth - goal
    b = velocity + omega * a
    decay = math.exp(-omega * dt)
    position = a + b * dt
    return goal + position * decay, (b - omega * position) * decay
