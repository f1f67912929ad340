"""Analysis of the estimators' statistics (numpy/scipy only).

* :mod:`~terrain_estimation.analysis.consistency` — NEES/NIS and e²/σ²
  statistics with effective sample counts; the nodes' diagnostics use it
  (core layer).
* :mod:`~terrain_analysis.pcrlb` — posterior Cramér–Rao lower
  bound (Tichavský et al. 1998) of any
  :class:`~terrain_estimation.filters.base.JacobianModel`, and the quarter
  car's, whose truth is simulated by ``vehicle_sim`` (offline analysis layer:
  import it as ``terrain_analysis.pcrlb``; this package does not
  re-export it, so that the core imports without the simulator).
"""
