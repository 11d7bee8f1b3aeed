"""GrandTour's Hugging Face release (one Zarr store per mission + JPEG folders) as ingest input.

`store` opens a mission and detects the format; `calib` reads the `tf` and camera_info
attributes; `read.ingest_hf` streams the topic groups into the recording index; `points` reads
LiDAR scans one chunk at a time (also for the packets stage).
"""
