"""The rover estimator's own model of wheel sinkage: Bekker's pressure–sinkage with nominal soil (issue 21).

A wheel on deformable soil rides below the undisturbed surface by its
sinkage s_j, which grows with its load W_j. Wheels under different loads
therefore ride at different depths: the three wheel centres are no longer
on the one path z_wc(x) that Estimator 1's geometry assumes, and a wheel
whose sinkage changes moves at ṡ_j off the surface it rolls on. Both bias
the contact angles γ̌ (eq. 79 with ż0^R from the path through the centres):
a wheel 5 mm deeper than the others 0.35 m away tilts the fitted path by
≈ 0.4°, i.e. ≈ 0.35 N of DP at W = 50 N.

This module is the estimator's model of that sinkage, from its own
estimated loads and nominal soil parameters, independent of any simulator:

* **Static sinkage** (Bekker's rigid-wheel solution, Wong, *Theory of Ground
  Vehicles*, eq. 2.52): the pressure–sinkage law p = (k_c/b + k_φ) z^n
  integrated over the front of the contact, with the chord approximated,
  gives z* = (3 W / ((3 − n) (k_c/b + k_φ) b √D))^(2/(2n+1)), D = 2r.
  With [RB] Table II's soil (n = 1.1, k_c b^(n−1) = 12 kPa,
  k_φ b^(n−1) = 1845.3 kPa/m for b = 70 mm) and the Kapvik wheel,
  z* ≈ 16.8 mm at 50 N and dz*/dW = (2/(2n+1)) z*/W ≈ 0.21 mm/N. Only the
  *differences* between the wheels and the *changes* of each wheel's
  sinkage enter γ̌ (a common depth shifts the fitted path without tilting
  it), so a bias common to the three wheels (Bekker's formula over-states
  shallow sinkage a little; slip-sinkage adds ≈ 0.5 mm from i = 0 to 0.4,
  alike on every wheel) does not matter.
* **Loading and unloading** (plastic soil): a rising load presses the soil
  at once (within a 0.2 s step); a falling load does not lift the wheel out
  of the rut it made — the soil does not spring back — and the rim climbs
  onto fresh soil over about one contact length l = r sin θ0 ≈ √(2 r z) of
  travel: ds/dx = −(s − z*)/l for s > z*.

The soil parameters are nominal (:class:`SinkageSoil`, [RB] Table II by
default); on another soil the sinkage differences scale as
(k_c/b + k_φ)^(−2/(2n+1)) (a soil twice as stiff: 0.65×), which is why the
considered contact-angle error keeps a share for it
(:class:`~terrain_estimation.estimators.rover_noise.ContactAngleBias`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from terrain_estimation.filters.base import Array

__all__ = ["SinkageSoil", "SinkageTracker", "static_sinkage"]


@dataclass(frozen=True, kw_only=True)
class SinkageSoil:
    """Nominal soil of the estimator's sinkage model (Bekker's pressure–sinkage law).

    Attributes:
        enabled: model the sinkage (False: every wheel on the path, s = ṡ = 0,
            the estimator before issue 21's plant sinkage).
        sinkage_exponent: n (–).
        cohesive_modulus: k_c b^(n−1) (Pa), i.e. k1 of [RB] Table II.
        frictional_modulus: k_φ b^(n−1) (Pa/m), i.e. k2 of [RB] Table II.
    """

    enabled: bool = True
    sinkage_exponent: float = 1.1
    cohesive_modulus: float = 12.0e3
    frictional_modulus: float = 1845.3e3

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sinkage_exponent) and 0.0 < self.sinkage_exponent < 3.0):
            raise ValueError(f"sinkage_exponent must be in (0, 3), got {self.sinkage_exponent!r}")
        for name in ("cohesive_modulus", "frictional_modulus"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and ≥ 0, got {value!r}")
        if self.cohesive_modulus + self.frictional_modulus <= 0.0:
            raise ValueError("cohesive_modulus + frictional_modulus must be > 0")


def static_sinkage(soil: SinkageSoil, load: ArrayLike, radius: float, width: float) -> Array:
    """Bekker's static sinkage z* (m) of a rigid wheel under ``load`` (N) (module docstring).

    With k1 = k_c b^(n−1), k2 = k_φ b^(n−1) the pressure under the rim is
    (k1/b + k2) z^n (the form of [RB] eq. 4); z* = (3 W / ((3 − n) b
    (k1/b + k2) √(2 r)))^(2/(2n+1)). Loads ≤ 0 give 0.
    """
    n = soil.sinkage_exponent
    k = soil.cohesive_modulus / width + soil.frictional_modulus
    w = np.maximum(np.asarray(load, dtype=float), 0.0)
    base = 3.0 * w / ((3.0 - n) * width * k * math.sqrt(2.0 * radius))
    return np.asarray(np.power(base, 2.0 / (2.0 * n + 1.0)), dtype=float)


class SinkageTracker:
    """Sinkage s_j of the three wheels over the estimator's steps (loading at once, unloading over travel).

    :meth:`step` takes each wheel's load and the distance travelled over the
    step and returns (s, ṡ): the sinkage at the end of the step and its
    mean rate over the step. The first call starts at the static sinkage
    (ṡ = 0).
    """

    def __init__(self, soil: SinkageSoil, radius: float, width: float) -> None:
        self.soil = soil
        self.radius = radius
        self.width = width
        self._s: Array | None = None

    def reset(self) -> None:
        self._s = None

    @property
    def sinkage(self) -> Array | None:
        """The last sinkage (m, (3,)), None before the first step."""
        return None if self._s is None else self._s.copy()

    def step(self, load: ArrayLike, travel: float, dt: float) -> tuple[Array, Array]:
        """(s (m), ṡ (m/s)) per wheel after a step of ``dt`` s and ``travel`` m under ``load`` (N)."""
        target = static_sinkage(self.soil, load, self.radius, self.width)
        if self._s is None or not np.isfinite(self._s).all():
            self._s = target
            return target.copy(), np.zeros_like(target)
        previous = self._s
        # Contact length l = r sin θ0 with cos θ0 = 1 − s/r.
        cos0 = np.clip(1.0 - previous / self.radius, -1.0, 1.0)
        length = np.maximum(self.radius * np.sqrt(np.maximum(1.0 - cos0 * cos0, 0.0)), 1e-4)
        climbed = target + (previous - target) * np.exp(-abs(travel) / length)
        s = np.where(target >= previous, target, climbed)
        self._s = s
        rate = (s - previous) / dt if dt > 0.0 else np.zeros_like(s)
        return s.copy(), rate
