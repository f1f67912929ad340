"""The rover reproduction's experiment: estimator variants, terrains, seeds, run counts, the paper's tables.

Part of :mod:`terrain_analysis.tools.reproduce_rover` (its docstring states the
seeds and the cases). The paper's numbers here are the comparison column of
the report only.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.estimators.rover import RoverEstimatorConfig
from vehicle_sim.plants.rover import TERRAIN_NUMBERS, TERRAINS

__all__ = [
    "ROOT_SEED",
    "VARIANTS",
    "PAPER_VARIANTS",
    "ALL_VARIANTS",
    "VARIANT_NAMES",
    "VARIANT_AXES",
    "VARIANT_BASE",
    "PAPER_CHOICES",
    "COLOURS",
    "paper_choices",
    "variant_config",
    "QUANTITIES",
    "Q_SYMBOL",
    "Q_UNIT",
    "FIT_TERRAINS",
    "TERRAIN_IDS",
    "CELL_FRACTION",
    "ESTIMATOR_SPEED_MIN",
    "SIMULATOR_SPEED_MIN",
    "GRID_POINTS",
    "PAPER_TABLE5",
    "PAPER_TABLE6",
    "COEFFICIENT_NAMES",
    "PAPER_TABLE7",
    "PAPER_SURROGATE_RMS",
    "PAPER_SURROGATE_RANGE",
    "Counts",
    "Task",
    "TerramechanicsName",
    "run_seed",
    "build_plan",
]

ROOT_SEED = 4005
"""Root of every seed of the reproduction (see the module docstring)."""

FloatArray = NDArray[np.float64]
TerramechanicsName = Literal["surrogate", "wong_reece"]

#: Estimator variants: Estimators 1 + 2 (two-axis load cells) and 1 + 3 (single-axis), with the
#: estimator's defaults (the project's estimators) ...
VARIANTS: tuple[str, ...] = ("e2", "e3")
#: ... and the same with every default that leaves the paper switched back to the paper's choice.
PAPER_VARIANTS: tuple[str, ...] = ("e2p", "e3p")
ALL_VARIANTS: tuple[str, ...] = VARIANTS + PAPER_VARIANTS
VARIANT_NAMES = {
    "e2": "E1+E2",
    "e3": "E1+E3",
    "e2p": "E1+E2, paper's choices",
    "e3p": "E1+E3, paper's choices",
}
VARIANT_AXES = {"e2": 2, "e3": 1, "e2p": 2, "e3p": 1}
#: Paper Table V row of each variant.
VARIANT_BASE = {"e2": "e2", "e3": "e3", "e2p": "e2", "e3p": "e3"}
#: :class:`RoverEstimatorConfig` fields whose defaults leave the paper, with the paper's choice
#: (the estimator module's docstring "Where the defaults leave the paper"); fields the
#: configuration does not have are skipped (and the report says which were set).
PAPER_CHOICES: dict[str, Any] = {
    "vertical_velocity": "zero",  # eq. 45: ż0^R = 0 in the contact angles
    "perpendicular_split": "load_cell",  # eq. 88
    "slip_rate_source": "imu",  # eq. 66 with the gyro's pitch rate
    "quasi_static_forces": False,  # eq. 59: net wheel forces as random walks
}
COLOURS = {"truth": "k", "e2": "tab:blue", "e3": "tab:red", "e2p": "tab:cyan", "e3p": "tab:orange"}


def paper_choices() -> dict[str, Any]:
    """The entries of :data:`PAPER_CHOICES` that :class:`RoverEstimatorConfig` has."""
    names = {f.name for f in dataclasses.fields(RoverEstimatorConfig)}
    return {k: v for k, v in PAPER_CHOICES.items() if k in names}


def variant_config(variant: str) -> RoverEstimatorConfig:
    """The estimator configuration of a variant (defaults, or the paper's choices)."""
    extra = paper_choices() if variant in PAPER_VARIANTS else {}
    return RoverEstimatorConfig(load_cell_axes=VARIANT_AXES[variant], **extra)


#: Table V quantities in the paper's column order, with symbol and unit.
QUANTITIES: tuple[str, ...] = ("slip", "normal_load", "resistive_torque", "drawbar_pull")
Q_SYMBOL = {"slip": "i", "normal_load": "W", "resistive_torque": "τ_R", "drawbar_pull": "DP"}
Q_UNIT = {"slip": "–", "normal_load": "N", "resistive_torque": "N·m", "drawbar_pull": "N"}

#: Terrains whose 2-s samples feed the model fits ([RB] V-C: terrain 6 excluded).
FIT_TERRAINS: tuple[int, ...] = (1, 2, 3, 4, 5)
TERRAIN_IDS: tuple[int, ...] = (1, 2, 3, 4, 5, 6)
#: The issue's requirement: at least this fraction of Table V's cells at or below the paper.
CELL_FRACTION = 0.8
#: The issue's speed requirements (multiples of real time).
ESTIMATOR_SPEED_MIN = 10.0
SIMULATOR_SPEED_MIN = 1.0
#: Grid of the local model and of Table VII ([RB] V-C: 100×100).
GRID_POINTS = 100

# Paper Table V (MODELS.md D.3): i1 i2 i3, W1 W2 W3, τ_R1 τ_R2 τ_R3, DP1 DP2 DP3.
PAPER_TABLE5: dict[tuple[int, str], tuple[float, ...]] = {
    (1, "e2"): (0.015, 0.015, 0.016, 0.15, 0.095, 0.3, 0.008, 0.0051, 0.0055, 0.88, 0.55, 0.47),
    (1, "e3"): (0.015, 0.015, 0.016, 0.21, 0.17, 0.31, 0.008, 0.0051, 0.0055, 1.8, 2.3, 0.49),
    (2, "e2"): (0.012, 0.012, 0.012, 0.094, 0.048, 0.076, 0.0038, 0.0028, 0.003, 0.53, 0.23, 0.35),
    (2, "e3"): (0.012, 0.012, 0.012, 0.1, 0.06, 0.078, 0.0038, 0.0028, 0.003, 0.65, 0.67, 0.4),
    (3, "e2"): (0.011, 0.011, 0.011, 0.059, 0.056, 0.069, 0.0024, 0.0023, 0.0024, 0.31, 0.18, 0.27),
    (3, "e3"): (0.011, 0.011, 0.011, 0.065, 0.065, 0.071, 0.0024, 0.0023, 0.0024, 0.41, 0.42, 0.31),
    (4, "e2"): (0.012, 0.012, 0.012, 0.06, 0.048, 0.092, 0.0032, 0.0025, 0.0027, 0.32, 0.23, 0.32),
    (4, "e3"): (0.012, 0.012, 0.012, 0.067, 0.061, 0.096, 0.0032, 0.0025, 0.0027, 0.56, 0.79, 0.38),
    (5, "e2"): (0.013, 0.013, 0.011, 0.086, 0.067, 0.21, 0.0039, 0.0029, 0.0031, 0.73, 0.51, 0.71),
    (5, "e3"): (0.013, 0.013, 0.011, 0.11, 0.14, 0.21, 0.0039, 0.0029, 0.0031, 0.88, 1.5, 0.75),
    (6, "e2"): (0.02, 0.02, 0.017, 0.15, 0.12, 0.37, 0.0068, 0.0047, 0.005, 1.7, 1.0, 1.3),
    (6, "e3"): (0.02, 0.02, 0.017, 0.23, 0.34, 0.38, 0.0068, 0.0047, 0.005, 1.7, 2.6, 1.3),
}
# Paper Table VI: p00 p10 p01 p20 p11 p02 (term p_kl i^k W^l; the coefficient order of fit_polynomial_2d).
PAPER_TABLE6: dict[str, tuple[float, ...]] = {
    "tau.local": (-0.367, 2.16, 0.0139, -2.7, 0.0266, 8.2e-5),
    "tau.e2": (0.777, 2.35, -0.0327, -2.48, 0.0156, 5.79e-4),
    "dp.local": (-4.17, 31.5, -0.032, -38.8, 0.274, -1.66e-4),
    "dp.e2": (11.8, 35.7, -0.685, -38.3, 0.122, 0.00673),
    "dp.e3": (9.33, 35.5, -0.579, -37.8, 0.127, 0.00562),
}
COEFFICIENT_NAMES = ("p00", "p10", "p01", "p20", "p11", "p02")
# Paper Table VII: (τ_R N·m, DP N).
PAPER_TABLE7: dict[str, tuple[float, float]] = {"e2": (0.0551, 0.747), "e3": (0.0554, 0.670)}
# Paper's 4th-order global surrogate over 0 ≤ i ≤ 1, 0.1 ≤ W ≤ 200 N (MODELS.md C.2).
PAPER_SURROGATE_RMS = {"dp": 0.1080, "tau": 0.008033}
PAPER_SURROGATE_RANGE = {"dp": (-9.406, 10.195), "tau": (0.0, 7.874)}


# ---------------------------------------------------------------------------
# Plan
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Counts:
    """Run counts and durations of one invocation (times in s).

    Attributes:
        seeds: sensor-noise runs per terrain (each with both estimator variants).
        duration: simulated time of every terrain; None: each terrain's own
            (200 s for terrains 1–3, 100 s for 4–6, :data:`~vehicle_sim.plants.rover.TERRAINS`).
        start_x: world x of the body CM at t = 0 (m).
        speed_duration: simulated time of each simulator-speed run (s).
        settle: the "settled" RMS variant skips estimates with t ≤ settle (s).
    """

    seeds: int = 4
    duration: float | None = None
    start_x: float = 0.0
    speed_duration: float = 30.0
    settle: float = 10.0

    @classmethod
    def quick(cls) -> Counts:
        """Smoke run: 4 s per terrain started on the terrain's feature, 2 seeds, 1 s speed runs."""
        return cls(seeds=2, duration=4.0, start_x=0.25, speed_duration=1.0, settle=1.0)

    def with_seeds(self, n: int) -> Counts:
        return replace(self, seeds=n)

    def terrain_duration(self, number: int) -> float:
        return float(TERRAINS[TERRAIN_NUMBERS[number]]().duration if self.duration is None else self.duration)


@dataclass(frozen=True)
class Task:
    """One job of the plan: a terrain (simulate once, estimate for every seed) or a simulator-speed run."""

    kind: Literal["terrain", "speed"]
    terrain: int
    duration: float
    seeds: int
    terramechanics: TerramechanicsName
    start_x: float = 0.0

    @property
    def label(self) -> str:
        """The job's name in progress lines and failures."""
        return f"terrain {self.terrain}" if self.kind == "terrain" else f"simulator speed, {self.terramechanics}"

    @property
    def cost(self) -> float:
        """Rough CPU seconds (the runner's weight: the order of the jobs and the progress estimate)."""
        if self.kind == "speed":
            return self.duration * (1.3 if self.terramechanics == "wong_reece" else 0.8)
        sim = 1.3 if self.terramechanics == "wong_reece" else 0.8
        return self.duration * (sim + 0.12 * self.seeds)


def run_seed(terrain: int, run: int) -> int:
    """Sensor-noise seed of run ``run`` on Fig. 10 terrain ``terrain``."""
    return int(np.random.SeedSequence([ROOT_SEED, terrain, run]).generate_state(1)[0])


def build_plan(counts: Counts, terramechanics: TerramechanicsName = "surrogate") -> list[Task]:
    """Every job: the six terrains and one speed run per terramechanics model."""
    plan = [
        Task("terrain", n, counts.terrain_duration(n), counts.seeds, terramechanics, counts.start_x)
        for n in TERRAIN_IDS
    ]
    plan += [Task("speed", 1, counts.speed_duration, 0, name) for name in ("wong_reece", "surrogate")]
    return plan
