"""Offline analysis of the terrain estimators: what runs on a desk, not on a robot.

The layer above the onboard core (:mod:`terrain_estimation`) and the simulator
(:mod:`vehicle_sim`); nothing below imports it (``test/test_import_graph.py``):

* :mod:`terrain_analysis.sim2real`: the sim-to-real diagnosis (where the model
  and the data disagree, which effect explains it, how far it shrinks);
* :mod:`terrain_analysis.batch`: ``terrain-batch``, estimation and diagnosis
  over many bags on a Dask cluster;
* :mod:`terrain_analysis.tools`: the demo, the reproductions of the papers,
  benchmarks, validation suites and the config generator;
* :mod:`terrain_analysis.pcrlb`: information bounds (they simulate the truth).
"""
