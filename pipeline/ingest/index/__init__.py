"""The recording index ingest writes (images, sweeps, odometry, rejects, damage tables)
and its result."""
