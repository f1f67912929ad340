"""Sim-to-real gap diagnosis (issue 6): where the nominal simulator disagrees with a bag."""

from terrain_analysis.sim2real.open_loop import SUPPORTED_VEHICLES, WhereReport, diagnose_where
from terrain_analysis.sim2real.where import Sim2RealError, WhereSettings

__all__ = ["SUPPORTED_VEHICLES", "Sim2RealError", "WhereReport", "WhereSettings", "diagnose_where"]
