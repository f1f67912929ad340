"""Per-step cost of the AdaptiveStrongTrackingUKF variants on the skid-steer observer model.

Not a test (no timed assertions anywhere): run it by hand,
``.venv/bin/python test/filters/bench_innovation_adaptation.py [steps] [rounds]``.

The estimator's hot path is ``filt._step`` on a checked state and measurement, one step per IMU
sample (100 Hz); 50× real time per core is 200 µs per step. The variants run interleaved, round
after round, on the same data (the model's own simulation, a 5 km/h turn), and the best round of
each is reported (the least disturbed by other load on the machine), with the median beside it.
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np

from terrain_estimation.filters import GaussianState
from terrain_estimation.filters.an_stukf import VARIANTS, AdaptiveStrongTrackingUKF
from terrain_estimation.models.skid_steer_observer import SkidSteerInput, SkidSteerObserverModel


def main(steps: int = 1000, rounds: int = 7) -> int:
    model = SkidSteerObserverModel()
    radius = model.params.wheel_radius
    u = SkidSteerInput(1.1 / radius, 1.6 / radius, 0.0, 0.2)
    dt = 0.01
    rng = np.random.default_rng(0)
    truth = SkidSteerObserverModel(max_euler_gain=0.05)
    x = np.array([1.35, 0.0, 0.15])
    zs = []
    for _ in range(steps):
        x = truth.f(x, u, dt) + rng.normal(scale=np.sqrt(model.q0_diag))
        zs.append(truth.h(x, u) + rng.normal(scale=np.sqrt(model.r0_diag)))
    times: dict[str, list[float]] = {v: [] for v in VARIANTS}
    for _ in range(rounds):
        for variant in VARIANTS:
            filt = AdaptiveStrongTrackingUKF(variant=variant)
            state = GaussianState(x=np.array([1.35, 0.0, 0.15]), P=np.diag([0.01, 0.01, 1e-4]))
            memory = None
            t0 = time.perf_counter()
            for z in zs:
                state, res = filt._step(state, state.x, z, model, u, dt, memory)
                memory = res.memory
            times[variant].append((time.perf_counter() - t0) / steps)
    base = min(times["ukf"])
    print(f"{'variant':18s} {'best µs/step':>12s} {'median':>8s} {'vs ukf':>7s}")
    for variant in VARIANTS:
        best = min(times[variant])
        print(f"{variant:18s} {best * 1e6:12.1f} {statistics.median(times[variant]) * 1e6:8.1f} {best / base:7.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(*(int(a) for a in sys.argv[1:])))
