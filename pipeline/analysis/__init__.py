"""Analysis over a finished output: packet accuracy, 2D-3D alignment, plots, the HTML report,
the Rerun viewer, SQL over the statistics tables and the model evaluation output. Above the
stages; nothing below imports it."""
