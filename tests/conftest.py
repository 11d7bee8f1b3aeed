"""Suite-wide settings: one torch thread (2-core machines stall otherwise), Agg plots."""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import torch

torch.set_num_threads(1)

pytest_plugins = ["tests.s3_fixture"]  # s3 / s3_env: a moto S3 server on 127.0.0.1
