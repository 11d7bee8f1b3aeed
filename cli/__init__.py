"""The `m3gd` command layer: the top of the import graph (commands -> dags -> pipeline).

One module per command group holds its commands as module-level functions; `cli.app`
assembles them. Imports of zarr, dask, open3d, torch, matplotlib and duckdb stay inside
the commands that need them, so `m3gd --help` starts without them.
"""
