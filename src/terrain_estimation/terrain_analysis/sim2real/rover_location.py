"""Where along the path a soil change starts: the start of the soil-change fit of the rover replay.

:class:`ChangeLocation` is a part of :class:`~terrain_analysis.sim2real.rover.RoverReplay`: a linearised
change-point scan of the nominal residual (:meth:`~ChangeLocation._change_location`), refined by the replay's own
training cost (:meth:`~ChangeLocation._refine_location`); the soil-change distance candidate starts there
(:meth:`~ChangeLocation._adapt_candidates`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.model import Candidate, Channel, FitParameter, ReplayModel

FloatArray = NDArray[np.float64]

_LOCATION_SCALE = 0.02  # m, scale of the soil-change distance started at the change-location scan
_LOCATION_WINDOW = 0.15  # m, either side of the linearised scan's location, of the replay's scan of it
_LOCATION_NFEV = 20  # evaluations of each fit of the soil scales in the location refinement
_LOCATION_ROUNDS = 3  # at most, of the location refinement (fit the scales, scan the location)


class ChangeLocation:
    """The soil-change location search of :class:`~terrain_analysis.sim2real.rover.RoverReplay` (its base class).

    Uses the replay's channels, measurements, domain mask and its :meth:`_compute` and :meth:`_wheel_x`.
    """

    channels: list[Channel]
    measured: dict[str, FloatArray]
    warmup: float
    _t: FloatArray
    _inside: NDArray[np.bool_]
    _soil_weights: FloatArray | None

    def _compute(
        self, effects: Mapping[str, Mapping[str, float]]
    ) -> tuple[dict[str, FloatArray], dict[str, FloatArray]]:
        raise NotImplementedError

    def _wheel_x(self) -> FloatArray:
        raise NotImplementedError

    def _adapt_candidates(self, catalogue: Mapping[str, Candidate]) -> dict[str, Candidate]:
        """The catalogue's candidates; the soil-change distance starts where the bag's residual says.

        The distance's bounds stay the catalogue's; its start (``off``, immaterial
        while the soil scales are 1) is the location :meth:`_change_location`
        finds on the wheel-centre positions the bag covers, 5 mm apart, else the
        middle of the wheels' travel.
        """
        out = dict(catalogue)
        if "soil_change" in out:
            found: float | None = None
            x = self._wheel_x()
            use = (self._t >= self._t[0] + self.warmup) & self._inside
            lo = max(0.0, float(np.min(x[use])))
            hi = min(10.0, float(np.max(x[use])))
            if hi > lo:
                count = int(min(200, max(2, math.ceil((hi - lo) / 5e-3) + 1)))
                found = self._change_location(np.linspace(lo, hi, count))
            params = []
            for prm in out["soil_change"].parameters:
                if prm.name == "soil_change_distance" and hi > lo:
                    if found is not None:
                        params.append(FitParameter(prm.name, prm.unit, found, prm.bounds, _LOCATION_SCALE))
                    else:
                        mid = 0.5 * (lo + hi)
                        params.append(FitParameter(prm.name, prm.unit, mid, prm.bounds, max(0.25 * (hi - lo), 1e-3)))
                else:
                    params.append(prm)
            out["soil_change"] = Candidate("soil_change", tuple(params), out["soil_change"].description)
        return out

    def _change_location(self, grid: FloatArray) -> float | None:
        """Where along the path a soil change would best explain the nominal residual (a start for the fit).

        A linearised change-point scan on the training part of the default
        split (:func:`~terrain_analysis.sim2real.attribution.held_out_mask`;
        the held-out part is never looked at). For each soil-change scale k
        (at its typical value) and wheel j, J_jk is the change of every channel
        (in units of σ) when wheel j alone runs on that soil over the whole
        bag (12 replays). A change at d then predicts the nominal residual
        r ≈ Σ_k β_k Σ_j [x_j ≥ d] J_jk, linear in β (the same soil under every
        wheel, as the plant's); the start is the d of the grid with the lowest
        residual sum of squares, refined by the replay itself
        (:meth:`_refine_location`). The fit's own gradient cannot move d far: the
        cost depends on it only through the few samples at the wheels'
        crossings, and it is flat while the scales are 1 (measured on the
        withheld-effect suite's six soil-change bags: started in the middle of
        the travel, the fit stayed 10–44 cm from the change on three; the
        linearised scan alone starts it within 14 mm on five, 12 cm off on the
        sixth, where a loose soil meets a sharp step and the linearisation
        prefers the later onset of the largest residual; with the refinement
        within 8 mm on all six, 1 mm on that one). None: nothing to scan.
        """
        from terrain_analysis.sim2real.attribution import AttributionSettings, held_out_mask
        from vehicle_sim.effects import CATALOGUE

        train, _ = held_out_mask(cast(ReplayModel, self), AttributionSettings())
        use = train[self.channels[0].name]
        if np.count_nonzero(use) < 10:
            return None
        effect = CATALOGUE["rover"]["soil_change"]
        names = [c.name for c in self.channels]
        sigma = np.array([c.noise_std for c in self.channels])
        _, nominal = self._compute({})
        residual = np.stack([(self.measured[c] - nominal[c])[use] for c in names], axis=1) / sigma
        scales = [p for p in effect.parameters if p.name != "soil_change_distance"]
        jac = np.zeros((3, len(scales), int(np.count_nonzero(use)), len(names)))
        values = {p.name: p.off for p in effect.parameters}
        try:
            for k, prm in enumerate(scales):
                changed = {**values, prm.name: prm.typical}
                for j in range(3):
                    weights = np.zeros((self._t.size, 3))
                    weights[:, j] = 1.0
                    self._soil_weights = weights.ravel()
                    _, pred = self._compute({"soil_change": changed})
                    jac[j, k] = np.stack([(pred[c] - nominal[c])[use] for c in names], axis=1) / sigma
        finally:
            self._soil_weights = None
        x = self._wheel_x()[use]
        target = residual.ravel()
        rss = np.full(grid.size, np.inf)
        for m, d in enumerate(grid):
            design = np.einsum("nj,jknc->nck", (x >= d).astype(float), jac).reshape(-1, len(scales))
            if not np.any(design):
                continue
            beta, *_ = np.linalg.lstsq(design, target, rcond=None)
            rss[m] = float(np.sum((target - design @ beta) ** 2))
        if not np.any(np.isfinite(rss)):
            return None
        return self._refine_location(float(grid[int(np.argmin(rss))]), grid, scales, train)

    def _refine_location(
        self, start: float, grid: FloatArray, scales: Sequence[Any], train: Mapping[str, NDArray[np.bool_]]
    ) -> float:
        """The linearised scan's location ``start`` corrected by the replay's own training cost.

        The linearisation (each wheel's response to a typical soil, scaled) misjudges a soil
        far from the typical one: a loose soil meeting a sharp step puts its lowest RSS 12 cm
        beyond the change. The replay's training cost is sharp at the change once the soil
        scales are right (a change put too early sends the wheels before it into the wrong
        soil; too late costs the samples in between). So the scales are fitted with the
        distance held at ``start`` (the engine's screen of starts: off, ± the typical change,
        an 11-point grid of each scale; then at most :data:`_LOCATION_NFEV` trust-region
        evaluations), the distance is scanned with them over the points of ``grid`` within
        :data:`_LOCATION_WINDOW`, and the two steps repeat from the lowest cost until the
        location stays (at most :data:`_LOCATION_ROUNDS` rounds: scales fitted 12 cm from the
        change put it 3 cm early on the test's rolling-terrain run, the second round on it).
        """
        from scipy import optimize

        names = [c.name for c in self.channels]
        sigma = {c.name: c.noise_std for c in self.channels}
        measured = {c: self.measured[c][train[c]] for c in names}

        def residual(distance: float, v: FloatArray) -> FloatArray:
            values = {"soil_change_distance": distance, **{p.name: float(x) for p, x in zip(scales, v, strict=True)}}
            pred = self._compute({"soil_change": values})[1]
            r = np.concatenate([(measured[c] - pred[c][train[c]]) / sigma[c] for c in names])
            return np.where(np.isfinite(r), r, 1e3)

        lo = np.array([p.fit_range[0] for p in scales])
        hi = np.array([p.fit_range[1] for p in scales])
        off = np.array([p.off for p in scales])
        typical = np.abs(np.array([p.typical for p in scales]) - off)
        span = hi - lo
        screen = [off]
        for k in range(len(scales)):
            for v in (off[k] + typical[k], off[k] - typical[k], *np.linspace(lo[k], hi[k], 11)):
                screen.append(np.where(np.arange(len(scales)) == k, v, off))
        costs = [float(np.sum(residual(start, np.clip(s, lo, hi)) ** 2)) for s in screen]
        fitted = screen[int(np.argmin(costs))]
        location = start
        for _ in range(_LOCATION_ROUNDS):
            first = np.clip(fitted, lo + 1e-6 * span, hi - 1e-6 * span)
            try:
                fitted = optimize.least_squares(
                    lambda v, d=location: residual(d, v),
                    first,
                    bounds=(lo, hi),
                    x_scale=typical,
                    max_nfev=_LOCATION_NFEV,
                    diff_step=1e-3,
                ).x
            except (ValueError, FloatingPointError):  # pragma: no cover - defensive
                fitted = first
            near = [float(d) for d in grid if abs(d - location) <= _LOCATION_WINDOW]
            if not near:
                break
            cost = [float(np.sum(residual(d, fitted) ** 2)) for d in near]
            moved = near[int(np.argmin(cost))]
            if moved == location:
                break
            location = moved
        return location
