"""``ilcpmac sweep``: many simulated campaigns, or identifications, with parameters drawn per task, on Dask.

`spec` reads the spec and draws each task's config; `task` is what one task runs and returns; `runner` runs
them on a Dask cluster; `results` holds the table and its percentiles; `plots` draws them (docs/sweep.md).
"""
