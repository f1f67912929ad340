"""Signal helpers of the rover replay: Savitzky–Golay smoothing, the white bound of a coloured noise, rotations."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy import signal

FloatArray = NDArray[np.float64]


@functools.lru_cache(maxsize=32)
def _savgol_operator(window: int, deriv: int, dt: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Quadratic Savitzky–Golay filter as (interior kernel, first-window map, last-window map).

    The edges are the quadratic fitted to the first / last ``window`` samples
    (scipy's ``mode="interp"``), as fixed linear maps so that every call is a
    convolution and two small products.
    """
    half = window // 2
    kernel = np.asarray(signal.savgol_coeffs(window, 2, deriv=deriv, delta=dt, use="conv"), dtype=float)
    x = np.arange(window, dtype=float)
    fit = np.linalg.pinv(np.vander(x, 3, increasing=True))  # (3, window): coefficients of 1, x, x²
    pos = np.arange(window, dtype=float)
    if deriv == 0:
        basis = np.vander(pos, 3, increasing=True)
    elif deriv == 1:
        basis = np.column_stack([np.zeros(window), np.ones(window), 2.0 * pos]) / dt
    else:
        basis = np.column_stack([np.zeros(window), np.zeros(window), 2.0 * np.ones(window)]) / dt**2
    full = basis @ fit  # (window, window): value at each position of the window
    return kernel, full[:half], full[window - half :]


def _savgol(x: FloatArray, window: int, deriv: int, dt: float) -> FloatArray:
    """Quadratic Savitzky–Golay smoothing / derivative along axis 0 (edges as scipy's ``mode="interp"``)."""
    window = max(5, window | 1)
    n = x.shape[0]
    if n <= window:
        window = (n - 1) | 1 if n % 2 == 0 else n - 2
        if window < 5:
            return np.gradient(x, dt, axis=0) if deriv else x.copy()
    kernel, first, last = _savgol_operator(window, deriv, round(dt, 12))
    half = window // 2
    if x.ndim == 1:
        out = np.empty(n)
        out[half : n - half] = np.convolve(x, kernel, mode="valid")
    else:
        out = np.empty(x.shape)
        for j in range(x.shape[1]):
            out[half : n - half, j] = np.convolve(x[:, j], kernel, mode="valid")
    out[:half] = first @ x[:window]
    out[n - half :] = last @ x[n - window :]
    return out


def _white_bound(samples: Sequence[FloatArray], rate: float) -> float:
    """σ of the white noise whose PSD bounds that of ``samples`` in every octave band above 0.5 Hz (and its variance).

    Welch PSD (Hann, 50 % overlap, ≈ 4 s segments as the noise tests use),
    mean over each octave band from 0.5 Hz to Nyquist; a white noise of
    variance σ² has the one-sided PSD 2σ²/rate.
    """
    variance = float(np.mean([np.var(x) for x in samples]))
    n = min(x.size for x in samples)
    nperseg = int(min(2 ** int(round(math.log2(max(rate * 4.0, 16.0)))), 2 ** int(math.log2(max(n // 8, 16)))))
    if n < 2 * nperseg:
        return math.sqrt(variance)
    spectra = [signal.welch(x, fs=rate, nperseg=nperseg, detrend="constant") for x in samples]
    f = spectra[0][0]
    psd = np.mean([p for _, p in spectra], axis=0)  # averaged over the realisations
    bound = variance
    low = 0.5
    while low < rate / 2.0:
        band = (f >= low) & (f < 2.0 * low)
        if np.any(band):
            bound = max(bound, float(np.mean(psd[band])) * rate / 2.0)
        low *= 2.0
    return math.sqrt(bound)


def _rotate(angle: FloatArray | float, bx: FloatArray, bz: FloatArray) -> tuple[FloatArray, FloatArray]:
    c, s = np.cos(angle), np.sin(angle)
    return bx * c + bz * s, -bx * s + bz * c
