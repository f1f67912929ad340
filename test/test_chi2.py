"""The filters' χ² numbers come without scipy.stats, and are the same floats.

``filters.chi2`` evaluates what ``scipy.stats.chi2`` does (``2 gammaincinv(df/2, q)``, ``chdtr``,
``chdtrc``) so that importing the filters, the ROS framework and the offline tool no longer imports
``scipy.stats`` (0.5 s of start-up, issue 23).
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from terrain_estimation.filters.chi2 import chi2_cdf, chi2_ppf, chi2_sf

PROBABILITIES = (0.0005, 0.0025, 0.005, 0.025, 0.05, 0.5, 0.95, 0.975, 0.99, 0.995, 0.999, 0.9999, 0.999999)
DOFS = (*range(1, 31), 2.5, 0.7, 50, 300, 3000, 30000)


def test_quantile_cdf_and_survival_are_scipy_stats_bit_for_bit() -> None:
    from scipy.stats import chi2

    for q in PROBABILITIES:
        for df in DOFS:
            x = float(chi2.ppf(q, df))
            assert chi2_ppf(q, df) == x, (q, df)
            for v in (x, 0.1, 3.0, 10.0):
                assert chi2_cdf(v, df) == float(chi2.cdf(v, df)), (v, df)
                assert chi2_sf(v, df) == float(chi2.sf(v, df)), (v, df)


@pytest.mark.parametrize("q", [0.0, 1.0, -0.1, float("nan")])
def test_a_probability_outside_the_open_interval_is_refused(q: float) -> None:
    with pytest.raises(ValueError, match="probability"):
        chi2_ppf(q, 3)


def test_the_offline_tool_and_the_skid_steer_node_import_without_scipy_stats() -> None:
    code = (
        "import sys\n"
        "import terrain_estimation.tools.estimate, terrain_estimation.ros.skid_steer\n"
        "import terrain_estimation.filters.faults, terrain_estimation.filters.noise_adaptation\n"
        "print('scipy.stats' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
