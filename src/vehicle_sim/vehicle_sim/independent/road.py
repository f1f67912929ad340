"""ISO 8608 road by a sum of harmonics, evaluated exactly on a uniform grid by an inverse FFT (MODELS.md A.8).

h(s) = Σ_i A_i cos(2π n_i s + φ_i), n_i = i/L, A_i = √(2 G_d(n_i) Δn), Δn = 1/L,
G_d(n) = G_d(n0) (n/n0)^(−2), n0 = 0.1 cycles/m, harmonics in [n_min, n_max]
and φ_i ~ U[0, 2π). On the grid s_j = j L/N the sum is exactly an inverse
real FFT, so the road, its slope and any linear filter of it (tire
enveloping below) are exact at every grid point: no interpolation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ISO_8608_GD", "Road", "iso8608_road"]

#: ISO 8608 class → geometric mean G_d(n0) (m³), n0 = 0.1 cycles/m (MODELS.md A.8 table).
ISO_8608_GD = {"A": 16e-6, "B": 64e-6, "C": 256e-6, "D": 1024e-6, "E": 4096e-6, "F": 16384e-6}
N0 = 0.1


@dataclass(frozen=True)
class Road:
    """A road on a uniform grid: spacing ``ds`` (m), elevation ``h`` (m) and slope ``dh`` (–) per grid point."""

    ds: float
    h: np.ndarray
    dh: np.ndarray
    spectrum: np.ndarray  # complex harmonic amplitudes (for filtered versions of the same road)
    length: float

    def filtered(self, gain: np.ndarray) -> Road:
        """The same road through a real, zero-phase spatial filter ``gain(n_i)`` (one value per harmonic)."""
        return _synthesise(self.spectrum * gain, self.h.size, self.ds)


def _synthesise(spectrum: np.ndarray, n: int, ds: float) -> Road:
    length = n * ds
    freq = np.arange(spectrum.size) / length
    h = np.fft.irfft(spectrum, n=n)
    dh = np.fft.irfft(spectrum * (2j * math.pi * freq), n=n)
    return Road(ds=ds, h=h, dh=dh, spectrum=spectrum, length=length)


def iso8608_road(
    road_class: str, rng: np.random.Generator, points: int, ds: float, band: tuple[float, float] = (0.05, 10.0)
) -> Road:
    """A random road of ``road_class`` on ``points`` grid points ``ds`` apart (m), harmonics in ``band`` (cycles/m)."""
    if road_class not in ISO_8608_GD:
        raise ValueError(f"unknown ISO 8608 class {road_class!r}; known: {', '.join(ISO_8608_GD)}")
    if points < 16 or not ds > 0.0:
        raise ValueError(f"road grid needs >= 16 points and ds > 0, got {points}, {ds}")
    length = points * ds
    dn = 1.0 / length
    freq = np.arange(points // 2 + 1) * dn
    inside = (freq >= band[0]) & (freq <= band[1]) & (freq > 0.0)
    amplitude = np.zeros(freq.size)
    amplitude[inside] = np.sqrt(2.0 * ISO_8608_GD[road_class] * (freq[inside] / N0) ** -2.0 * dn)
    phase = rng.uniform(0.0, 2.0 * math.pi, freq.size)
    # irfft(X)[j] = Σ_i Re(X_i e^{2πi ij/N}) · 2/N for 0 < i < N/2: X_i = A_i e^{iφ_i} N/2.
    spectrum = amplitude * np.exp(1j * phase) * (points / 2.0)
    return _synthesise(spectrum, points, ds)
