"""Select stage: nearest sweep per image, Δτ, and the LiDAR-to-camera chain."""

from pipeline.select.views import SelectResult, select_views

__all__ = ["SelectResult", "select_views"]
