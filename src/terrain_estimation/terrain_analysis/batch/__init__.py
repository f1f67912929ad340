"""Running many independent jobs (bags, Monte Carlo runs) on a Dask distributed cluster (issue 23).

* :mod:`~terrain_analysis.batch.engine` — the engine: map a function over
  tasks, each isolated (an exception, even a dead worker, is a recorded
  failure), with a progress bar and CPU time per task, on a local cluster of
  one worker process per core or on a running cluster (``--scheduler``).
  Any long job of the project can use it (``validate-sim2real``, the
  ``reproduce-*`` tools).
* :mod:`~terrain_analysis.batch.worker_setup` — a function run once in every
  worker, including restarted ones (``Engine.setup_workers``: a pool's
  ``initializer``).
* :mod:`~terrain_analysis.batch.forkserver_preload` — what the forkserver the
  local workers are forked from imports and warms once
  (:func:`~terrain_analysis.batch.engine.preload_workers`).
* :mod:`~terrain_analysis.batch.bags` — what ``terrain-batch`` does with one
  bag: vehicle detection, estimation and/or diagnosis, the resumability
  fingerprint and the summary row.
"""
