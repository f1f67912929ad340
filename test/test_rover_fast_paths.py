"""The rover replay's fast paths (issue 23) give the numbers of the paths they replace, bit for bit.

* the adapter's bulk handlers (``RoverAdapter.field_handlers``) against one message at a time;
* ``filters.sigma_points.solve`` against ``np.linalg.solve``;
* ``SigmaPointKalmanFilter.update_with_moments`` against ``update`` then ``measurement_moments``;
* ``models.rover.dynamics_gravity`` against ``dynamics_terms(...).gravity``;
* ``statistical_linearisation`` + ``block_part`` against ``process_block_part``.
"""

# ruff: noqa: N806 - matrix symbols

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from terrain_estimation.estimators.rover_noise import block_part, process_block_part, statistical_linearisation
from terrain_estimation.filters.base import GaussianState
from terrain_estimation.filters.sigma_points import solve
from terrain_estimation.filters.ukf import UnscentedKalmanFilter
from terrain_estimation.models.rover import RoverParams, dynamics_gravity, dynamics_terms

BAG = Path(__file__).resolve().parents[1] / "bags" / "rover_terrain_1"


def _digest(run: object) -> list[object]:
    return [(topic, ns, repr(msg)) for topic, msg, ns in run.outputs]  # type: ignore[attr-defined]


@pytest.mark.skipif(not BAG.exists(), reason="shipped rover bag not present")
@pytest.mark.parametrize("axes", [2, 1])
def test_bulk_handlers_match_message_path(axes: int) -> None:
    from terrain_estimation.tools.estimate import estimate_bag

    overrides = {"estimator.load_cell_axes": axes}
    bulk = estimate_bag(BAG, "rover", overrides=overrides, bulk=True)
    one_by_one = estimate_bag(BAG, "rover", overrides=overrides, bulk=False)
    assert bulk.outputs and _digest(bulk) == _digest(one_by_one)
    assert bulk.rejected == one_by_one.rejected and bulk.accepted == one_by_one.accepted


def test_field_handlers_cover_the_fixed_layout_inputs() -> None:
    from terrain_estimation.tools.estimate import config_values
    from terrain_estimation.vehicles import get_vehicle

    entry = get_vehicle("rover")
    adapter = entry.make_adapter(config_values(entry), entry.namespace)
    assert set(adapter.field_handlers) == {"imu", "velocimeter", "load_rear", "load_middle", "load_front"}


def test_solve_is_numpy_solve_bit_for_bit() -> None:
    rng = np.random.default_rng(5)
    for n in (2, 3, 4, 11):
        A = rng.normal(size=(n, n)) + n * np.eye(n)
        b = rng.normal(size=n)
        B = rng.normal(size=(n, 3))
        assert np.array_equal(solve(A, b), np.linalg.solve(A, b))
        assert np.array_equal(solve(A, B), np.linalg.solve(A, B))
        assert np.array_equal(solve(A, B.T.copy().T), np.linalg.solve(A, B.T.copy().T))  # non-contiguous
        assert np.array_equal(solve(A, B[:, 0]), np.linalg.solve(A, B[:, 0]))
    assert np.array_equal(solve(np.array([[2, 0], [0, 4]]), np.array([1, 1])), [0.5, 0.25])  # ints: numpy's path
    with pytest.raises(np.linalg.LinAlgError):
        solve(np.zeros((3, 3)), np.ones(3))


class _Model:
    """A small nonlinear model (2 states, 2 measurements), vectorised over points."""

    state_dim = 2
    measurement_dim = 2

    def f(self, x: np.ndarray, u: object, dt: float) -> np.ndarray:
        return x + dt * np.sin(x[..., ::-1])

    def h(self, x: np.ndarray, u: object) -> np.ndarray:
        return np.stack([x[..., 0] * x[..., 1], np.cos(x[..., 0])], axis=-1)

    def process_noise_sqrt(self, x: np.ndarray, u: object, dt: float) -> np.ndarray:
        return 0.1 * np.eye(2)

    def measurement_noise_sqrt(self) -> np.ndarray:
        return 0.2 * np.eye(2)


def test_update_with_moments_is_update_and_moments() -> None:
    flt = UnscentedKalmanFilter()
    model = _Model()
    prior = GaussianState(x=np.array([0.3, -0.7]), P=np.array([[0.2, 0.05], [0.05, 0.1]]))
    z = np.array([-0.1, 0.9])
    Rs = np.diag([0.3, 0.1])
    post, info = flt.update(prior, z, model, None, measurement_noise_sqrt=Rs)
    mm = flt.measurement_moments(prior, model, None, measurement_noise_sqrt=Rs)
    post2, info2, mm2 = flt.update_with_moments(prior, z, model, None, measurement_noise_sqrt=Rs)
    assert np.array_equal(post.x, post2.x) and np.array_equal(post.P, post2.P)
    assert info.nis == info2.nis and np.array_equal(info.innovation, info2.innovation)
    for name in ("z_hat", "P_zz", "P_xz", "R"):
        assert np.array_equal(getattr(mm, name), getattr(mm2, name))


def test_dynamics_gravity_is_dynamics_terms_gravity() -> None:
    rng = np.random.default_rng(9)
    params = RoverParams()
    for _ in range(50):
        g = rng.normal(size=7) * [1.0, 1.0, 0.4, 0.4, 3.0, 3.0, 3.0]
        g_dot = rng.normal(size=7)
        assert np.array_equal(dynamics_gravity(params, g), dynamics_terms(params, g, g_dot).gravity)


def test_shared_linearisation_is_process_block_part() -> None:
    rng = np.random.default_rng(2)
    M = rng.normal(size=(9, 9))
    P = M @ M.T + 9 * np.eye(9)
    P_xz = rng.normal(size=(9, 9))
    Ht = statistical_linearisation(P_xz, P)
    for _ in range(9):
        L = rng.normal(size=(9, 1))
        Q = L @ L.T
        assert np.array_equal(block_part(Ht, Q), process_block_part(P_xz, P, Q))
