"""Road elevation profiles h(s) as exact analytic functions of the distance s.

ISO 8608 random roads are synthesised as a seeded sum of harmonics
(Agostinacchio, Ciampa, Olita 2014; MODELS.md A.8)::

    h(s)    =  Σ_i A_i cos(2π n_i s + φ_i)
    dh/ds   = −Σ_i 2π n_i A_i sin(2π n_i s + φ_i)

so elevation and slope are exact at any distance — the truth plant evaluates
them at every integration stage, and the road rate the estimator needs is
ḣ = v · dh/ds (MODELS.md A.3).

ISO 8608 displacement PSD (one-sided, cycles/m)::

    G_d(n) = G_d(n0) (n/n0)^(−w),   n0 = 0.1 cycles/m,   w = 2

with the class geometric means of MODELS.md A.8.

**Band.** The default band is 0.05–10 cycles/m. 0.05 cycles/m is ISO 8608's lower
limit for off-road use; 10 cycles/m is the practical upper limit set by tire
enveloping (a contact patch of 0.1–0.2 m filters shorter wavelengths; tire
enveloping is not modelled here). MODELS.md A.8 suggests 0.05–3 cycles/m to keep
the road below the 10 ms filter's Nyquist frequency; this truth road deliberately
keeps content above it (10 cycles/m at 10 m/s is 100 Hz, twice the 50 Hz Nyquist
of a 100 Hz filter), because a real road has it and MODELS.md A.10 shows the road
between filter steps decides the k_s error. The estimator sees that content
through the 1 kHz profile sampler (Nyquist 500 Hz ≥ 10 cycles/m × 50 m/s).

**Frequency grid.** Two spacings:

* ``"log"`` (default): N log-spaced bins over the band, one harmonic per bin at a
  random (log-uniform) frequency inside the bin, with A_i² / 2 equal to the exact
  integral of G_d over the bin. The expected PSD is exact, the road never
  repeats, and N ≈ 2000 harmonics cover 0.05–10 cycles/m with ~0.3 % relative
  frequency resolution — cheap enough to evaluate at every integration stage.
* ``"uniform"``: Agostinacchio's literal grid n_i = n_min + iΔn, Δn = 1/L,
  A_i = √(2 G_d(n_i) Δn). Needs (n_max − n_min)·L harmonics (10 k for 1 km) and
  repeats after L metres.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

__all__ = [
    "DEFAULT_BAND",
    "ISO8608_CLASSES",
    "ISO8608_GD_N0",
    "ISO8608_N0",
    "ISO8608_WAVINESS",
    "FlatProfile",
    "HarmonicProfile",
    "PsdCheck",
    "RoadProfile",
    "check_iso8608_psd",
    "fit_iso8608",
    "flat_profile",
    "iso8608_class_of",
    "iso8608_class_range",
    "iso8608_profile",
    "meadow_c_standin",
    "power_law_profile",
    "sinusoidal_profile",
    "welch_elevation_psd",
]

ISO8608_N0 = 0.1
"""Reference spatial frequency n0 (cycles/m)."""

ISO8608_WAVINESS = 2.0
"""ISO 8608 waviness exponent w (dimensionless)."""

ISO8608_CLASSES = ("A", "B", "C", "D", "E", "F", "G", "H")

ISO8608_GD_N0: Mapping[str, float] = MappingProxyType({cls: 16e-6 * 4**i for i, cls in enumerate(ISO8608_CLASSES)})
"""Class geometric-mean G_d(n0) (m³): A 16e-6, B 64e-6, …, H 262144e-6 (MODELS.md A.8)."""

DEFAULT_BAND = (0.05, 10.0)
"""Default spatial-frequency band (cycles/m); see the module docstring."""

# Elements per block of trigonometric evaluation: bounds temporaries to ~16 MB.
_BLOCK_ELEMENTS = 1 << 20
# Points per block of the phasor-rotation evaluation on uniform grids.
_UNIFORM_BLOCK = 256


def iso8608_class_range(road_class: str) -> tuple[float, float]:
    """Range of G_d(n0) (m³) of an ISO 8608 class: [mean/2, 2·mean).

    Class A starts at 0 and class H is open above (``inf``).
    """
    mean = ISO8608_GD_N0[_check_class(road_class)]
    low = 0.0 if road_class.upper() == "A" else mean / 2.0
    high = math.inf if road_class.upper() == "H" else mean * 2.0
    return low, high


def iso8608_class_of(gd_n0: float) -> str:
    """ISO 8608 class letter whose G_d(n0) range contains ``gd_n0`` (m³)."""
    if not gd_n0 > 0.0:
        raise ValueError(f"G_d(n0) must be > 0, got {gd_n0}")
    for road_class in ISO8608_CLASSES:
        if gd_n0 < iso8608_class_range(road_class)[1]:
            return road_class
    return "H"


def _check_class(road_class: str) -> str:
    key = road_class.upper()
    if key not in ISO8608_GD_N0:
        raise ValueError(f"unknown ISO 8608 class {road_class!r}; expected one of A–H")
    return key


class RoadProfile:
    """Base class of road elevation profiles h(s), s the distance travelled (m).

    Subclasses implement :meth:`elevation_and_slope`; the other methods derive
    from it and may be overridden for speed.

    Attributes:
        name: Short identifier, e.g. ``"iso8608_D"``.
        description: One line saying what the profile is, with its parameters.
    """

    name: str = "profile"
    description: str = ""

    def elevation_and_slope(self, distance: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Elevation h (m) and slope dh/ds (dimensionless) at distances s (m).

        Args:
            distance: s (m), any shape.

        Returns:
            ``(h, dh_ds)``, each of the shape of ``distance``.
        """
        raise NotImplementedError

    def elevation(self, distance: ArrayLike) -> NDArray[np.float64]:
        """Elevation h (m) at distances s (m); shape of ``distance``."""
        return self.elevation_and_slope(distance)[0]

    def slope(self, distance: ArrayLike) -> NDArray[np.float64]:
        """Slope dh/ds (m/m) at distances s (m); shape of ``distance``."""
        return self.elevation_and_slope(distance)[1]

    def evaluate_uniform(
        self, start: float, spacing: float, count: int
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Elevation and slope on the grid s_j = start + j·spacing, j = 0..count−1.

        Args:
            start: First distance (m).
            spacing: Grid step (m), may be 0.
            count: Number of points.

        Returns:
            ``(h, dh_ds)``, each of shape (count,).
        """
        return self.elevation_and_slope(start + spacing * np.arange(count))


class FlatProfile(RoadProfile):
    """Level road: h(s) = 0, dh/ds = 0."""

    name = "flat"
    description = "flat road, h = 0"

    def elevation_and_slope(self, distance: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        zeros = np.zeros(np.shape(distance))
        return zeros, zeros.copy()

    def evaluate_uniform(
        self, start: float, spacing: float, count: int
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.zeros(count), np.zeros(count)

    def __repr__(self) -> str:
        return "FlatProfile()"


class HarmonicProfile(RoadProfile):
    """Sum of cosines h(s) = Σ A_i cos(2π n_i s + φ_i), evaluated exactly.

    Args:
        spatial_frequencies: n_i (cycles/m), shape (N,), ≥ 0.
        amplitudes: A_i (m), shape (N,).
        phases: φ_i (rad), shape (N,).
        name: Short identifier.
        description: What the profile is (class, band, seed …).

    Attributes:
        spatial_frequencies, amplitudes, phases: Read-only copies, shape (N,).
    """

    def __init__(
        self,
        spatial_frequencies: ArrayLike,
        amplitudes: ArrayLike,
        phases: ArrayLike,
        *,
        name: str = "harmonic",
        description: str = "",
    ) -> None:
        freqs = np.array(spatial_frequencies, dtype=float).ravel()
        amps = np.array(amplitudes, dtype=float).ravel()
        phis = np.array(phases, dtype=float).ravel()
        if not (freqs.shape == amps.shape == phis.shape):
            raise ValueError(
                f"frequencies, amplitudes and phases must have equal length, got "
                f"{freqs.shape}, {amps.shape}, {phis.shape}"
            )
        if np.any(freqs < 0.0) or not np.all(np.isfinite(freqs)):
            raise ValueError("spatial frequencies must be finite and ≥ 0 cycles/m")
        for arr in (freqs, amps, phis):
            arr.setflags(write=False)
        self.spatial_frequencies = freqs
        self.amplitudes = amps
        self.phases = phis
        self.name = name
        self.description = description
        self._wavenumbers = 2.0 * np.pi * freqs  # rad/m
        self._rotation_cache: OrderedDict[tuple[float, int], tuple[NDArray[np.float64], NDArray[np.float64]]] = (
            OrderedDict()
        )

    @property
    def n_harmonics(self) -> int:
        """Number of harmonics N."""
        return int(self.spatial_frequencies.size)

    @property
    def rms_elevation(self) -> float:
        """Exact rms of h over an infinite road (m): √(Σ A_i²/2)."""
        return float(np.sqrt(0.5 * np.sum(self.amplitudes**2)))

    def elevation_and_slope(self, distance: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        s = np.asarray(distance, dtype=float)
        flat = s.ravel()
        h = np.empty(flat.size)
        dh = np.empty(flat.size)
        n = max(self.n_harmonics, 1)
        block = max(1, _BLOCK_ELEMENTS // n)
        a = self.amplitudes
        ka = self._wavenumbers * a
        for lo in range(0, flat.size, block):
            theta = np.multiply.outer(flat[lo : lo + block], self._wavenumbers)
            theta += self.phases
            h[lo : lo + block] = np.cos(theta) @ a
            dh[lo : lo + block] = -(np.sin(theta) @ ka)
        return h.reshape(s.shape), dh.reshape(s.shape)

    def evaluate_uniform(
        self, start: float, spacing: float, count: int
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Exact h and dh/ds on a uniform grid by phasor rotation.

        e^{iθ_i(s0 + jΔs)} = e^{iθ_i(s0)} · e^{i 2π n_i jΔs}: the rotation
        (cos and sin of 2π n_i jΔs) depends only on (Δs, block length) and is
        cached, so a block costs N cosines and sines plus two real matrix
        products instead of N × block of each. Every factor is computed
        directly (no repeated multiplication), so the result is exact to
        rounding. Real arithmetic on purpose: complex GEMM of these shapes is
        pathologically slow in some BLAS builds.

        Args:
            start: First distance s0 (m).
            spacing: Δs (m), may be 0.
            count: Number of points.

        Returns:
            ``(h, dh_ds)``, each of shape (count,).
        """
        count = int(count)
        h = np.zeros(count)
        dh = np.zeros(count)
        if count == 0 or self.n_harmonics == 0:
            return h, dh
        block = min(count, _UNIFORM_BLOCK)
        rot_cos, rot_sin = self._rotation(float(spacing), block)
        a = self.amplitudes
        ka = self._wavenumbers * a
        columns = np.empty((self.n_harmonics, 4))
        for lo in range(0, count, block):
            m = min(block, count - lo)
            theta = self._wavenumbers * (start + lo * spacing) + self.phases
            cos0, sin0 = np.cos(theta), np.sin(theta)
            columns[:, 0] = a * cos0
            columns[:, 1] = a * sin0
            columns[:, 2] = ka * cos0
            columns[:, 3] = ka * sin0
            p = rot_cos[:m] @ columns
            q = rot_sin[:m] @ columns
            # cos(θ0 + δ) = cosθ0 cosδ − sinθ0 sinδ;  sin(θ0 + δ) = sinθ0 cosδ + cosθ0 sinδ.
            h[lo : lo + m] = p[:, 0] - q[:, 1]
            dh[lo : lo + m] = -(p[:, 3] + q[:, 2])
        return h, dh

    def _rotation(self, spacing: float, block: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        key = (spacing, block)
        rotation = self._rotation_cache.get(key)
        if rotation is None:
            delta = np.multiply.outer(spacing * np.arange(block), self._wavenumbers)
            rotation = (np.cos(delta), np.sin(delta))
            self._rotation_cache[key] = rotation
            # A few entries suffice: one per (speed, rate) in use at a time.
            while len(self._rotation_cache) > 8:
                self._rotation_cache.popitem(last=False)
        else:
            self._rotation_cache.move_to_end(key)
        return rotation

    def __repr__(self) -> str:
        return f"HarmonicProfile(name={self.name!r}, n_harmonics={self.n_harmonics})"


def power_law_profile(
    gd_n0: float,
    seed: int,
    *,
    waviness: float = ISO8608_WAVINESS,
    n0: float = ISO8608_N0,
    band: tuple[float, float] = DEFAULT_BAND,
    spacing: Literal["log", "uniform"] = "log",
    n_harmonics: int = 2000,
    length: float | None = None,
    name: str = "power_law",
    description: str = "",
) -> HarmonicProfile:
    """Random road with PSD G_d(n) = gd_n0 (n/n0)^(−w) by a seeded sum of harmonics.

    Args:
        gd_n0: G_d(n0) (m³).
        seed: Seed of the random phases (and in-bin frequencies for ``"log"``).
        waviness: w (dimensionless), 2 for ISO 8608.
        n0: Reference spatial frequency (cycles/m).
        band: (n_min, n_max) (cycles/m), 0 < n_min < n_max.
        spacing: ``"log"`` (default) or ``"uniform"`` (Agostinacchio et al. 2014);
            see the module docstring.
        n_harmonics: Number of log-spaced bins (``"log"`` only).
        length: Profile length L (m) setting Δn = 1/L (``"uniform"`` only).
        name: Identifier of the profile.
        description: Overrides the generated description.

    Returns:
        The profile.
    """
    n_min, n_max = (float(x) for x in band)
    if not 0.0 < n_min < n_max:
        raise ValueError(f"band must satisfy 0 < n_min < n_max, got {band}")
    if not gd_n0 >= 0.0:
        raise ValueError(f"G_d(n0) must be ≥ 0, got {gd_n0}")
    rng = np.random.default_rng(seed)

    def psd(n: NDArray[np.float64]) -> NDArray[np.float64]:
        return gd_n0 * (n / n0) ** (-waviness)

    if spacing == "log":
        if n_harmonics < 1:
            raise ValueError(f"n_harmonics must be ≥ 1, got {n_harmonics}")
        edges = np.geomspace(n_min, n_max, n_harmonics + 1)
        lower, upper = edges[:-1], edges[1:]
        freqs = lower * (upper / lower) ** rng.random(n_harmonics)
        # Exact ∫ G_d over each bin, so the expected variance per bin is exact.
        if math.isclose(waviness, 1.0):
            band_power = gd_n0 * n0 * np.log(upper / lower)
        else:
            e = 1.0 - waviness
            band_power = gd_n0 * n0**waviness * (upper**e - lower**e) / e
        amps = np.sqrt(2.0 * band_power)
        grid = f"{n_harmonics} log-spaced harmonics"
    elif spacing == "uniform":
        if length is None or not length > 0.0:
            raise ValueError("spacing='uniform' needs a profile length L > 0 (m)")
        dn = 1.0 / length
        freqs = np.asarray(n_min + dn * np.arange(int(math.floor((n_max - n_min) / dn + 1e-9)) + 1), dtype=np.float64)
        amps = np.asarray(np.sqrt(2.0 * psd(freqs) * dn), dtype=np.float64)  # Agostinacchio et al. 2014
        grid = f"{freqs.size} harmonics at Δn = 1/{length:g} m"
    else:
        raise ValueError(f"spacing must be 'log' or 'uniform', got {spacing!r}")
    phases = rng.uniform(0.0, 2.0 * np.pi, freqs.size)
    if not description:
        description = (
            f"G_d(n0={n0:g})={gd_n0:.6g} m^3, w={waviness:g}, band {n_min:g}-{n_max:g} cycles/m, {grid}, seed {seed}"
        )
    return HarmonicProfile(freqs, amps, phases, name=name, description=description)


def iso8608_profile(
    road_class: str,
    seed: int,
    *,
    band: tuple[float, float] = DEFAULT_BAND,
    spacing: Literal["log", "uniform"] = "log",
    n_harmonics: int = 2000,
    length: float | None = None,
) -> HarmonicProfile:
    """ISO 8608 random road of a class A–H at the class geometric mean G_d(n0).

    Args:
        road_class: ``"A"`` … ``"H"`` (case-insensitive).
        seed: Seed of the realisation.
        band: (n_min, n_max) (cycles/m); default 0.05–10 (module docstring).
        spacing: ``"log"`` or ``"uniform"`` (module docstring).
        n_harmonics: Number of bins for ``"log"``.
        length: Profile length (m) for ``"uniform"``.

    Returns:
        The profile, named ``"iso8608_<class>"``.
    """
    key = _check_class(road_class)
    profile = power_law_profile(
        ISO8608_GD_N0[key],
        seed,
        band=band,
        spacing=spacing,
        n_harmonics=n_harmonics,
        length=length,
        name=f"iso8608_{key}",
    )
    profile.description = f"ISO 8608 class {key}: {profile.description}"
    return profile


def meadow_c_standin(
    seed: int,
    *,
    band: tuple[float, float] = DEFAULT_BAND,
    spacing: Literal["log", "uniform"] = "log",
    n_harmonics: int = 2000,
    length: float | None = None,
) -> HarmonicProfile:
    """Stand-in for the paper's "harsh Meadow-c" profile (Ohmiya 1986).

    Ohmiya's PSD parameters were not found (MODELS.md A.8, [recon]). The paper
    calls Meadow-c harsh, between its ISO D and F cases, so this is ISO 8608
    class E at its geometric mean: G_d(n0) = 4096e-6 m³, w = 2. It is labelled
    ``meadow_c_standin`` wherever it appears so no result passes it off as
    Ohmiya's measured field.

    Args:
        seed: Seed of the realisation.
        band: (n_min, n_max) (cycles/m).
        spacing: ``"log"`` or ``"uniform"``.
        n_harmonics: Number of bins for ``"log"``.
        length: Profile length (m) for ``"uniform"``.

    Returns:
        The profile, named ``"meadow_c_standin"``.
    """
    profile = power_law_profile(
        ISO8608_GD_N0["E"],
        seed,
        band=band,
        spacing=spacing,
        n_harmonics=n_harmonics,
        length=length,
        name="meadow_c_standin",
    )
    profile.description = "Meadow-c stand-in (Ohmiya 1986 PSD not found): ISO 8608 class E, " + profile.description
    return profile


def flat_profile() -> FlatProfile:
    """A level road, h = 0."""
    return FlatProfile()


def sinusoidal_profile(amplitude: float, wavelength: float, phase: float = 0.0) -> HarmonicProfile:
    """Single harmonic h(s) = amplitude · cos(2π s / wavelength + phase).

    Args:
        amplitude: m.
        wavelength: m, > 0.
        phase: rad.

    Returns:
        The profile.
    """
    if not wavelength > 0.0:
        raise ValueError(f"wavelength must be > 0 m, got {wavelength}")
    return HarmonicProfile(
        [1.0 / wavelength],
        [amplitude],
        [phase],
        name="sinusoid",
        description=f"sinusoid, amplitude {amplitude:g} m, wavelength {wavelength:g} m",
    )


# ---------------------------------------------------------------------------
# PSD check (Welch) of a realisation against an ISO 8608 class.
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PsdCheck:
    """Welch PSD of a profile realisation, fitted to the ISO 8608 form.

    Attributes:
        spatial_frequency: n (cycles/m), shape (K,).
        psd: One-sided displacement PSD G_d(n) (m³), shape (K,).
        band: (n_min, n_max) (cycles/m) used for the fits.
        gd_n0: G_d(n0) (m³) fitted with w fixed at the ISO value 2.
        waviness: w fitted freely (log-log least squares).
        road_class: Class whose G_d(n0) range contains ``gd_n0``.
        expected_class: Class the profile was generated for.
        within_class: ``road_class == expected_class``.
    """

    spatial_frequency: NDArray[np.float64]
    psd: NDArray[np.float64]
    band: tuple[float, float]
    gd_n0: float
    waviness: float
    road_class: str
    expected_class: str
    within_class: bool


def welch_elevation_psd(
    elevation: ArrayLike, spacing: float, segment_length: float = 50.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One-sided displacement PSD of equally spaced elevation samples (Welch, Hann).

    Args:
        elevation: h (m), shape (M,).
        spacing: Sample spacing Δs (m).
        segment_length: Welch segment length (m); resolution 1/segment_length.

    Returns:
        ``(n, G_d)``: spatial frequency (cycles/m) and PSD (m³), each (K,).
    """
    h = np.asarray(elevation, dtype=float)
    nperseg = min(h.size, max(8, int(round(segment_length / spacing))))
    n, g = signal.welch(h, fs=1.0 / spacing, window="hann", nperseg=nperseg, detrend="constant")
    return n, g


def fit_iso8608(
    spatial_frequency: ArrayLike,
    psd: ArrayLike,
    band: tuple[float, float],
    n0: float = ISO8608_N0,
    waviness: float = ISO8608_WAVINESS,
) -> tuple[float, float]:
    """Fit G_d(n) = G_d(n0)(n/n0)^(−w) to a PSD inside a band.

    Frequencies are weighted equally per log interval (log-spaced resampling)
    so the many high-frequency Welch bins do not dominate.

    Args:
        spatial_frequency: n (cycles/m), (K,).
        psd: G_d (m³), (K,).
        band: (n_min, n_max) (cycles/m) of the fit.
        n0: Reference frequency (cycles/m).
        waviness: w held fixed for the G_d(n0) estimate.

    Returns:
        ``(gd_n0, w_fit)``: G_d(n0) with w fixed (geometric mean of
        G·(n/n0)^w over the band), and the freely fitted w.
    """
    n = np.asarray(spatial_frequency, dtype=float)
    g = np.asarray(psd, dtype=float)
    mask = (n >= band[0]) & (n <= band[1]) & (g > 0.0)
    if np.count_nonzero(mask) < 3:
        raise ValueError(f"fewer than 3 PSD bins inside band {band}")
    log_n = np.log(n[mask])
    log_g = np.log(g[mask])
    # Equal weight per log interval: weight each bin by its log-width ≈ Δn/n.
    weights = 1.0 / n[mask]
    weights /= weights.sum()
    gd_n0 = float(np.exp(np.sum(weights * (log_g + waviness * (log_n - math.log(n0))))))
    x = log_n - math.log(n0)
    x_mean = np.sum(weights * x)
    y_mean = np.sum(weights * log_g)
    slope = np.sum(weights * (x - x_mean) * (log_g - y_mean)) / np.sum(weights * (x - x_mean) ** 2)
    return gd_n0, float(-slope)


def check_iso8608_psd(
    profile: RoadProfile,
    road_class: str,
    *,
    length: float = 1000.0,
    spacing: float = 0.025,
    start: float = 0.0,
    band: tuple[float, float] = (0.1, 5.0),
    segment_length: float = 50.0,
) -> PsdCheck:
    """Sample a profile, estimate its PSD (Welch) and compare with an ISO class.

    The default fit band 0.1–5 cycles/m stays inside the synthesis band and
    above the Welch resolution (1/segment_length); the sampling spacing keeps
    the Nyquist frequency (20 cycles/m) above the 10 cycles/m synthesis limit.

    Args:
        profile: Profile to check.
        road_class: Expected class A–H.
        length: Sampled length (m).
        spacing: Sample spacing (m).
        start: First sampled distance (m).
        band: Fit band (cycles/m).
        segment_length: Welch segment (m).

    Returns:
        The check result.
    """
    key = _check_class(road_class)
    count = int(round(length / spacing))
    h, _ = profile.evaluate_uniform(start, spacing, count)
    n, g = welch_elevation_psd(h, spacing, segment_length)
    gd_n0, w_fit = fit_iso8608(n, g, band)
    estimated = iso8608_class_of(gd_n0)
    return PsdCheck(
        spatial_frequency=n,
        psd=g,
        band=band,
        gd_n0=gd_n0,
        waviness=w_fit,
        road_class=estimated,
        expected_class=key,
        within_class=estimated == key,
    )
