"""DAG stages: each plans items on the driver and runs one item anywhere."""
