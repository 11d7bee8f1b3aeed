"""The cache store: reading and writing m3gd's Zarr v3 cache, locally, through tensorstore and on
S3 (the writer `cache_store`/`shard_writer`, the pread reader `shard_reader`, the S3 mirror
`shard_cache`). Declarations of the layout stay in `schemas`."""
