"""The sampler's temperature: chosen on validation recordings, recorded in the checkpoint.

The paper's sampler starts from z_1 ~ N(0, I) (temperature 1, `model.sampler.sample`): a
draw, whose spread a PSNR score pays for. `m3gd train --val-recordings N` holds N training
recordings out of training (`val_recordings`: a fixed draw from the sorted names, as the
science bench's), and after the last update scores K-step samples of their clips at every
temperature of `TEMPERATURES`; the one of the highest mean PSNR (the lowest on a tie,
`pick`) is recorded in the checkpoint's metadata under "sampler" (`SAMPLER_VERSION`,
`sampler_block`). `m3gd sample` and `m3gd eval` use it by default (`resolve_temperature`):
--temperature, then a temperature set in the configuration, then the checkpoint's, then 1
(the paper's) with a note for a checkpoint that records none.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from model.checkpoint import load_checkpoint, save_checkpoint
from schemas.errors import DataError

if TYPE_CHECKING:
    from model.dataset import ClipStream

TEMPERATURES = (0.0, 0.25, 0.5, 1.0)
"""The grid the validation recordings choose from (1: the paper's sampler)."""
SAMPLER_KEY = "sampler"
"""Key of the sampler block in a checkpoint's metadata."""
SAMPLER_VERSION = 1
"""Version of that block: {"version", "temperature", "steps", "guidance", "val_psnr",
"recordings", "clips"}."""
PAPER_TEMPERATURE = 1.0
VAL_SEED = 12345
"""Seed of the draw of validation recordings (`bench.science.val_recordings`'s)."""


def pick(val_psnr: dict[float, float]) -> float:
    """The temperature of the highest validation PSNR (dB); ties go to the lowest
    temperature (the more deterministic sampler). A ValueError on an empty grid."""
    if not val_psnr:
        raise ValueError("no temperature scored on the validation recordings")
    best = max(val_psnr.values())
    return min(t for t, p in val_psnr.items() if p == best)


def val_recordings(names: Sequence[str], n: int) -> list[str]:
    """`n` of the training recordings `names` held out for validation: a fixed draw
    (seed `VAL_SEED`) from the sorted names, sorted; a DataError unless 0 < n < len(names)
    (training needs a recording left)."""
    unique = sorted(set(names))
    if not 0 < n < len(unique):
        raise DataError(f"--val-recordings {n}: the training split has {len(unique)} "
                        f"recording(s); hold out at least 1 and leave at least 1 to train on")
    rng = np.random.default_rng(VAL_SEED)
    return sorted(unique[i] for i in rng.choice(len(unique), n, replace=False))


def hold_out(stream: ClipStream, recordings: Sequence[str], keep: bool) -> ClipStream:
    """`stream` with only the clips of `recordings` (keep) or of all others (not keep), in
    place; a DataError naming the recordings when none is left."""
    held = set(recordings)
    stream.clips = [c for c in stream.clips if (c["recording"] in held) == keep]
    if not stream.clips:
        raise DataError(f"no clip left {'in' if keep else 'outside'} the validation "
                        f"recordings {sorted(held)}")
    return stream


@dataclass(frozen=True)
class Choice:
    """How a temperature is chosen: K Euler steps, guidance s, the first `clips` clips of
    the validation recordings in batches of `batch_size`, noise seed, the grid."""

    steps: int
    guidance: float
    clips: int
    batch_size: int
    seed: int
    temperatures: tuple[float, ...] = TEMPERATURES


def sampler_block(val_psnr: dict[float, float], choice: Choice, recordings: Sequence[str],
                  clips: int) -> dict[str, Any]:
    """The checkpoint's "sampler" metadata (JSON) of validation PSNRs (dB) per temperature."""
    return {"version": SAMPLER_VERSION, "temperature": pick(val_psnr),
            "steps": choice.steps, "guidance": choice.guidance,
            "val_psnr": {f"{t:g}": p for t, p in sorted(val_psnr.items())},
            "recordings": list(recordings), "clips": clips}


def choose_temperature(score: Callable[[float], tuple[float, int]], choice: Choice,
                       recordings: Sequence[str]) -> dict[str, Any]:
    """The sampler block of the temperature `score` rates best: score(T) -> (mean PSNR dB of
    the K-step samples at temperature T on the validation clips, clips scored)."""
    val, clips = {}, 0
    for t in choice.temperatures:
        val[t], clips = score(t)
    return sampler_block(val, choice, recordings, clips)


def record_sampler(path: Path, block: dict[str, Any]) -> None:
    """Rewrite the checkpoint in directory `path` with `block` as its "sampler" metadata
    (atomically, `model.checkpoint.save_checkpoint`; tensors unchanged)."""
    tensors, meta = load_checkpoint(path)
    meta = {k: v for k, v in meta.items() if k not in ("format", "tensors_sha256")}
    save_checkpoint(path, tensors, {**meta, SAMPLER_KEY: block})


def recorded_temperature(meta: dict[str, Any]) -> float | None:
    """The temperature a checkpoint's metadata records (None: none, or a sampler block of
    another version, which this m3gd does not read)."""
    block = meta.get(SAMPLER_KEY)
    if not isinstance(block, dict) or block.get("version") != SAMPLER_VERSION:
        return None
    return float(block["temperature"])


def resolve_temperature(explicit: float | None, configured: float | None,
                        meta: dict[str, Any]) -> tuple[float, str, str | None]:
    """(temperature, where it came from, a note or None) for sampling a checkpoint.

    explicit: --temperature; configured: sample.temperature when the configuration sets it
    (None otherwise); meta: the checkpoint's metadata. Order: explicit, configured, the
    checkpoint's validation-chosen temperature, else 1 (the paper's) with a note.
    """
    if explicit is not None:
        return explicit, "--temperature", None
    if configured is not None:
        return configured, "config sample.temperature", None
    recorded = recorded_temperature(meta)
    if recorded is not None:
        block = meta[SAMPLER_KEY]
        return (recorded, f"the checkpoint's (chosen on {len(block['recordings'])} "
                          f"validation recording(s) at K={block['steps']})", None)
    return (PAPER_TEMPERATURE, "the paper's (the checkpoint records none)",
            "the checkpoint records no sampler temperature (trained without "
            "--val-recordings, or by an older m3gd): sampling at temperature 1, the paper's; "
            "pass --temperature to choose another")
