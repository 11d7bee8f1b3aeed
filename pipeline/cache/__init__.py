"""Sharded Zarr v3 cache: open, create, shard-aligned atomic writes, completion marks."""
