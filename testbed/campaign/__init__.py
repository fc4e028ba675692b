"""Monte Carlo campaigns: scenarios x trackers x seeds x parameter grids, run on a process pool or Dask.

* :mod:`testbed.campaign.spec`: campaign files (strict TOML), the run plan and the common-random-number seeds;
* :mod:`testbed.campaign.engine`: one run in a worker, the local process pool and Dask backends;
* :mod:`testbed.campaign.store`: the results directory (one atomic parquet file per finished run);
* :mod:`testbed.campaign.report`: mean / sd / 95 % CI tables and plots, ``report.md``;
* :mod:`testbed.cli.campaign`: ``testbed campaign run|resume|report``.

This package imports nothing heavy at import time: worker processes are started with ``spawn`` and set
their thread limits before numpy, open3d or highway-env load (see :func:`engine.init_worker`).
See ``docs/campaigns.md``.
"""
