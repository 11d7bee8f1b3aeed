"""A run of the m3gd stage graph under the run policy (`pipeline.run.service`), with the
product's hooks: `s3://` recordings are listed by the ingest staging, and `verify` checks the
cache's chunk checksums (`pipeline.cache.verify`). Commands, benches and tests that mean a
run call `run_graph`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console

from dags.graph import STAGES
from pipeline.run.service import RunEvents, RunHooks, RunOutcome, RunRequest, run_stages
from schemas.config import M3GDConfig


def verify_cache(out: Path) -> Any:
    """(report, forgotten items) of `pipeline.cache.verify.verify_output` on `out`: a damaged
    array's writer stage and its dependants in the stage graph are redone."""
    from pipeline.cache.verify import verify_output
    from pipeline.run.stage import downstream_of

    return verify_output(out, lambda stage: downstream_of(STAGES, stage))


def list_recording(location: Path) -> Any:
    """The bags of an `s3://` recording (StorageError when it cannot be listed)."""
    from pipeline.ingest.sources.staging import mission_identity

    return mission_identity(location)


HOOKS = RunHooks(check_recording=list_recording, verify=verify_cache)
"""The product's hooks of the run policy."""


def run_graph(cfg: M3GDConfig, request: RunRequest | None = None,
              events: RunEvents | None = None, console: Console | None = None) -> RunOutcome:
    """Run the stage graph `dags.graph.STAGES` for `cfg` (see `pipeline.run.service`)."""
    return run_stages(cfg, STAGES, request, HOOKS, events, console)
