"""Soils of Table 1, series-spring algebra and Bekker utilities (MODELS.md A.2)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vehicle_sim.terrain.soils import (
    BEKKER_PARAMETERS_UNVERIFIED,
    GRANEVILLE_LOAM,
    LETE_SAND,
    LUNAR_REGOLITH,
    NORTH_GOWER_CLAYEY_LOAM,
    RUBICON_SANDY_LOAM,
    SOILS,
    TABLE1_SOILS,
    UPLAND_SANDY_LOAM,
    Soil,
    SoilPath,
    bekker_pressure,
    flat_contact_equivalent_stiffness,
    flat_contact_static_sinkage,
    k_s_error_amplification,
    k_s_from_k_tot,
    k_tot,
    nearest_soil,
    rigid_wheel_equivalent_stiffness,
    rigid_wheel_load,
    rigid_wheel_static_sinkage,
    soil_by_name,
)

TIRE_STIFFNESS = 175e3

# Table 1 (k_s) and the derived columns of MODELS.md A.2, in kN/m.
TABLE1 = [
    (UPLAND_SANDY_LOAM, 218.1, 97.09, 2.25),
    (LETE_SAND, 2283.0, 162.54, 14.05),
    (RUBICON_SANDY_LOAM, 272.1, 106.50, 2.55),
    (NORTH_GOWER_CLAYEY_LOAM, 221.9, 97.84, 2.27),
    (GRANEVILLE_LOAM, 651.1, 137.93, 4.72),
]


@pytest.mark.parametrize(("soil", "k_s_kn", "k_tot_kn", "gain"), TABLE1)
def test_table1_values_and_derived_columns(soil, k_s_kn, k_tot_kn, gain):
    assert soil.k_s == pytest.approx(k_s_kn * 1e3, rel=1e-12)
    assert soil.k_tot(TIRE_STIFFNESS) / 1e3 == pytest.approx(k_tot_kn, abs=0.006)
    assert k_s_error_amplification(soil.k_tot(TIRE_STIFFNESS), TIRE_STIFFNESS) == pytest.approx(gain, abs=0.006)


def test_soil_registry():
    assert TABLE1_SOILS == tuple(row[0] for row in TABLE1)
    assert set(SOILS) == {soil.name for soil in TABLE1_SOILS} | {"lunar_regolith"}
    assert soil_by_name("lete_sand") is LETE_SAND
    assert LUNAR_REGOLITH.k_s == 28.487e3
    assert all(soil.display_name for soil in SOILS.values())
    with pytest.raises(KeyError, match="known"):
        soil_by_name("quicksand")
    with pytest.raises(ValueError):
        Soil("bad", "Bad", 0.0)


def test_lrv_regolith_k_tot():
    # Table 5: k = 15 kN/m in series with regolith gives 9.826 kN/m (MODELS.md A.7).
    assert LUNAR_REGOLITH.k_tot(15e3) == pytest.approx(9826.0, abs=0.5)


@settings(max_examples=200, deadline=None)
@given(
    k_s=st.floats(min_value=1e2, max_value=1e8),
    k=st.floats(min_value=1e3, max_value=1e7),
)
def test_k_tot_k_s_round_trip(k_s, k):
    combined = k_tot(k_s, k)
    assert 0.0 < combined < k
    assert k_s_from_k_tot(combined, k) == pytest.approx(k_s, rel=1e-6)
    assert k_tot(k_s_from_k_tot(combined, k), k) == pytest.approx(combined, rel=1e-12)


def test_series_spring_arrays_and_limits():
    k_s = np.array([soil.k_s for soil in TABLE1_SOILS])
    combined = k_tot(k_s, TIRE_STIFFNESS)
    assert combined.shape == (5,)
    np.testing.assert_allclose(k_s_from_k_tot(combined, TIRE_STIFFNESS), k_s, rtol=1e-12)
    assert k_tot(math.inf, TIRE_STIFFNESS) == TIRE_STIFFNESS
    assert isinstance(k_tot(1e5, 2e5), float)


@pytest.mark.parametrize("bad", [0.0, -1.0, TIRE_STIFFNESS, 2 * TIRE_STIFFNESS, math.nan])
def test_k_s_from_k_tot_rejects_values_outside_open_interval(bad):
    with pytest.raises(ValueError, match="0 < k_tot < k"):
        k_s_from_k_tot(bad, TIRE_STIFFNESS)


def test_k_tot_rejects_non_positive_stiffness():
    with pytest.raises(ValueError):
        k_tot(0.0, TIRE_STIFFNESS)
    with pytest.raises(ValueError):
        k_tot(1e5, -1.0)
    with pytest.raises(ValueError):
        k_s_from_k_tot(np.array([1e4, 2e5]), TIRE_STIFFNESS)


def test_nearest_soil_in_log_space():
    assert nearest_soil(600e3) is GRANEVILLE_LOAM
    assert nearest_soil(3000e3) is LETE_SAND
    assert nearest_soil(30e3, [LUNAR_REGOLITH, LETE_SAND]) is LUNAR_REGOLITH


def test_soil_path_lookup():
    path = SoilPath([(0.0, LETE_SAND), (100.0, UPLAND_SANDY_LOAM), (200.0, GRANEVILLE_LOAM)])
    assert path.soil_at(0.0) is LETE_SAND
    assert path.soil_at(99.999) is LETE_SAND
    assert path.soil_at(100.0) is UPLAND_SANDY_LOAM
    assert path.soil_at(1e6) is GRANEVILLE_LOAM
    np.testing.assert_array_equal(
        path.k_s_at([50.0, 150.0, 250.0]),
        [LETE_SAND.k_s, UPLAND_SANDY_LOAM.k_s, GRANEVILLE_LOAM.k_s],
    )
    assert SoilPath(LETE_SAND) == SoilPath([(0.0, LETE_SAND)])
    with pytest.raises(ValueError, match="increase"):
        SoilPath([(0.0, LETE_SAND), (0.0, UPLAND_SANDY_LOAM)])
    with pytest.raises(ValueError, match="≤ 0"):
        SoilPath([(5.0, LETE_SAND)])


# MODELS.md A.2 [check]: the rigid-wheel formula with the tabulated (unverified)
# Bekker parameters gives these, not Table 1.
RIGID_WHEEL_KN = {
    "upland_sandy_loam": 113.0,
    "lete_sand": 384.0,
    "rubicon_sandy_loam": 103.0,
    "north_gower_clayey_loam": 244.0,
    "graneville_loam": 236.0,
}


@pytest.mark.parametrize(("name", "expected_kn"), sorted(RIGID_WHEEL_KN.items()))
def test_rigid_wheel_stiffness_matches_independent_check(name, expected_kn):
    params = BEKKER_PARAMETERS_UNVERIFIED[name]
    assert "UNVERIFIED" in params.source
    k_s = rigid_wheel_equivalent_stiffness(4905.0, 0.777, 0.265, params)
    assert k_s / 1e3 == pytest.approx(expected_kn, abs=1.0)


def test_rigid_wheel_lrv_regolith():
    params = BEKKER_PARAMETERS_UNVERIFIED["lunar_regolith"]
    assert rigid_wheel_equivalent_stiffness(735.0, 1.016, 0.254, params) / 1e3 == pytest.approx(36.7, abs=0.1)


@pytest.mark.parametrize("name", sorted(BEKKER_PARAMETERS_UNVERIFIED))
def test_bekker_functions_are_consistent(name):
    params = BEKKER_PARAMETERS_UNVERIFIED[name]
    load, diameter, width = 4905.0, 0.777, 0.265
    z0 = rigid_wheel_static_sinkage(load, diameter, width, params)
    assert rigid_wheel_load(z0, diameter, width, params) == pytest.approx(load, rel=1e-12)
    dz = 1e-7 * z0
    slope = (
        rigid_wheel_load(z0 + dz, diameter, width, params) - rigid_wheel_load(z0 - dz, diameter, width, params)
    ) / (2 * dz)
    assert rigid_wheel_equivalent_stiffness(load, diameter, width, params) == pytest.approx(slope, rel=1e-6)
    pressure = 40e3
    z_flat = flat_contact_static_sinkage(pressure, width, params)
    assert bekker_pressure(z_flat, width, params) == pytest.approx(pressure, rel=1e-12)
    assert flat_contact_equivalent_stiffness(load, pressure, width, params) == pytest.approx(params.n * load / z_flat)
