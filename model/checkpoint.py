"""Checkpoints without pickle: one safetensors file carrying the tensors and the state.

Layout of a checkpoint directory (format m3gd-checkpoint/2):
  checkpoint.safetensors  tensors model.<name>, ema.<name>, opt.<param index>.<state key>;
                          header metadata {"m3gd": JSON {"format": FORMAT, "step": int,
                          "net": {...}, "train": {...}, "param_groups": [...],
                          "opt_keys": {...}, "extra": {...}, "tensors_sha256": hex}}
One file is one atomic unit: it is written to a temporary beside its place, flushed to
disk and renamed over the old one, so a kill at any point leaves the old checkpoint or the
new one, never a mix (the kill-window test runs every prefix of `save_steps`). On load the
SHA-256 of the tensors is checked against the header, and the optimizer's update count
against the step.

Format 1 (tensors.safetensors + state.json, written one after the other) is still read;
a pair whose optimizer step differs from state.json's step (a save cut between the two
files) is refused in one line.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file
from torch import Tensor

from schemas.errors import DataError

FORMAT = "m3gd-checkpoint/2"
FILE = "checkpoint.safetensors"
META_KEY = "m3gd"
LEGACY_FORMAT = "m3gd-checkpoint/1"
TENSORS = "tensors.safetensors"
STATE = "state.json"


def flatten_optimizer(opt: torch.optim.Optimizer) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Optimizer state as tensors {opt.<i>.<key>} plus JSON {param_groups, opt_keys}."""
    sd = opt.state_dict()
    tensors: dict[str, Tensor] = {}
    keys: dict[str, list[str]] = {}
    for idx, st in sd["state"].items():
        keys[str(idx)] = []
        for k, v in st.items():
            if not isinstance(v, Tensor):
                raise TypeError(f"optimizer state {idx}.{k} is not a tensor: {type(v).__name__}")
            tensors[f"opt.{idx}.{k}"] = v.detach().clone().contiguous()
            keys[str(idx)].append(k)
    return tensors, {"param_groups": sd["param_groups"], "opt_keys": keys}


def unflatten_optimizer(tensors: dict[str, Tensor], meta: dict[str, Any]) -> dict[str, Any]:
    """Inverse of `flatten_optimizer`: a dict for `Optimizer.load_state_dict`."""
    state = {int(i): {k: tensors[f"opt.{i}.{k}"] for k in ks} for i, ks in meta["opt_keys"].items()}
    groups = [{**g, "betas": tuple(g["betas"])} if "betas" in g else g
              for g in meta["param_groups"]]
    return {"state": state, "param_groups": groups}


def tensors_sha256(tensors: dict[str, Tensor]) -> str:
    """SHA-256 over every tensor's name, dtype, shape and bytes, in name order."""
    h = hashlib.sha256()
    for k in sorted(tensors):
        v = tensors[k].detach().contiguous().cpu()
        h.update(f"{k}|{v.dtype}|{tuple(v.shape)}|".encode())
        h.update(v.reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def _fsync(path: Path) -> None:
    """Flush a file or directory to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def save_steps(path: Path, tensors: dict[str, Tensor], meta: dict[str, Any]
               ) -> list[tuple[str, Callable[[], None]]]:
    """The file operations of one save, in order (named); `save_checkpoint` runs them all.

    A kill between any two leaves `path` loading as the old checkpoint or the new one.
    """
    tensors = {k: v.detach().contiguous() for k, v in tensors.items()}
    state = {"format": FORMAT, **meta, "tensors_sha256": tensors_sha256(tensors)}
    final, tmp = path / FILE, path / f".{FILE}.{os.getpid()}.tmp"

    def clear_stale() -> None:
        remove_temporaries(path)  # left by a killed save

    def drop_legacy() -> None:
        for name in (STATE, TENSORS):  # format 1 beside it would only confuse a reader
            (path / name).unlink(missing_ok=True)

    return [("mkdir", lambda: path.mkdir(parents=True, exist_ok=True)),
            ("clear stale temporaries", clear_stale),
            ("write temporary", lambda: save_file(tensors, str(tmp),
                                                  metadata={META_KEY: json.dumps(state)})),
            ("fsync temporary", lambda: _fsync(tmp)),
            ("rename into place", lambda: os.replace(tmp, final)),
            ("fsync directory", lambda: _fsync(path)),
            ("remove format-1 files", drop_legacy)]


def save_checkpoint(path: Path, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
    """Write `tensors` and `meta` (JSON-compatible) as the checkpoint in directory `path`."""
    for _name, op in save_steps(path, tensors, meta):
        op()


WRITER_TEMP = re.compile(r"\.tmp[A-Za-z0-9]{6}")
"""Name of the temporary safetensors' own writer makes beside the file it writes (Rust's
`tempfile`: `.tmp` and 6 random letters or digits), renamed onto our temporary when whole:
the one file a save killed inside `save_file` leaves."""


def temporaries(path: Path) -> list[Path]:
    """The temporaries of saves into directory `path`: ours
    (`.checkpoint.safetensors.<pid>.tmp`) and the safetensors writer's (`WRITER_TEMP`),
    left there only by a save that was killed (or one running now)."""
    if not path.is_dir():
        return []
    return sorted([*path.glob(f".{FILE}.*.tmp"),
                   *(p for p in path.glob(".tmp*") if WRITER_TEMP.fullmatch(p.name)
                     and p.is_file())])


def remove_temporaries(path: Path) -> int:
    """Remove the temporaries of killed saves from directory `path`; return their bytes."""
    freed = 0
    for stale in temporaries(path):
        try:
            freed += stale.stat().st_size
            stale.unlink()
        except FileNotFoundError:
            pass
    return freed


def has_checkpoint(path: Path) -> bool:
    """Whether directory `path` holds a checkpoint (either format)."""
    return (path / FILE).is_file() or (path / STATE).is_file()


def read_meta(path: Path) -> dict[str, Any]:
    """The state of the checkpoint in `path` without reading its tensors."""
    try:
        if (path / FILE).is_file():
            with safe_open(str(path / FILE), framework="pt") as f:
                header = f.metadata() or {}
            meta: dict[str, Any] = json.loads(header[META_KEY])
        else:
            meta = json.loads((path / STATE).read_text())
    except Exception as err:  # OSError, JSON, a missing key, safetensors' own error type
        raise DataError(f"{path}: not a readable m3gd checkpoint ({err})") from err
    if meta.get("format") not in (FORMAT, LEGACY_FORMAT):
        raise DataError(f"{path}: checkpoint format {meta.get('format')!r}, expected {FORMAT!r}")
    return meta


def load_checkpoint(path: Path) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Tensors and state of the checkpoint in `path`, checked (hash, optimizer step)."""
    meta = read_meta(path)
    new = meta["format"] == FORMAT
    where = path / (FILE if new else TENSORS)
    try:
        tensors = load_file(str(where))
    except Exception as err:
        raise DataError(f"{where}: not a readable m3gd checkpoint ({err})") from err
    if new and tensors_sha256(tensors) != meta.get("tensors_sha256"):
        raise DataError(f"{where}: tensors do not match the SHA-256 in its header (the file "
                        "is damaged); resume from another checkpoint or start over (--force)")
    check_step(where, tensors, meta)
    return tensors, meta


def optimizer_updates(tensors: dict[str, Tensor]) -> int | None:
    """AdamW's update count stored with the tensors (None before the first update)."""
    steps = [int(v.item()) for k, v in tensors.items()
             if k.startswith("opt.") and k.endswith(".step")]
    return max(steps) if steps else None


def check_step(where: Path, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
    """Refuse tensors whose optimizer update count is not the state's step (minus the updates
    an fp16 loss scaler skipped): a format-1 pair cut between its two writes."""
    updates = optimizer_updates(tensors)
    expected = int(meta["step"]) - int(meta.get("skipped", 0))
    if updates is not None and updates != expected:
        raise DataError(f"{where}: tensors of optimizer step {updates} with the state of step "
                        f"{meta['step']} (a save was cut between its files); resume from "
                        "another checkpoint or start over (--force)")


def prefixed(tensors: dict[str, Tensor], prefix: str) -> dict[str, Tensor]:
    """Entries under `prefix.` with the prefix stripped."""
    n = len(prefix) + 1
    return {k[n:]: v for k, v in tensors.items() if k.startswith(prefix + ".")}


RUN_FILE = "run.json"
"""What a training run fixed when it started, beside its checkpoint (`write_run`)."""
RUN_FORMAT = "m3gd-train-run/1"


def write_run(path: Path, val_recordings: list[str]) -> None:
    """Record in directory `path` (atomically, `RUN_FILE`) what a resumed run must keep:
    the validation recordings held out of training (names; [] for none)."""
    from schemas.atomic_io import write_text_atomic

    write_text_atomic(path / RUN_FILE, json.dumps(
        {"format": RUN_FORMAT, "val_recordings": sorted(val_recordings)}))


def read_run(path: Path) -> list[str] | None:
    """The validation recordings `write_run` recorded in directory `path`, else those of the
    checkpoint's sampler block (a finished run written before the record); None when
    neither names them. A DataError names a record that cannot be read."""
    where = path / RUN_FILE
    if where.is_file():
        try:
            run = json.loads(where.read_text())
            if run.get("format") != RUN_FORMAT:
                raise ValueError(f"format {run.get('format')!r}, expected {RUN_FORMAT!r}")
            return [str(r) for r in run["val_recordings"]]
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
            raise DataError(f"{where}: not a readable run record ({err})") from err
    block = read_meta(path).get("sampler") if has_checkpoint(path) else None
    return None if not isinstance(block, dict) else [str(r) for r in block["recordings"]]
