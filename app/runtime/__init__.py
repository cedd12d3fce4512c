"""Where and how work runs: the Dask cluster, the one task runner, the run store and its
manifest, progress, the dashboard page, the run lock, checks before any cluster starts, faults."""
