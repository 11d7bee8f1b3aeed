"""Checkpoints are one atomic unit: a kill between any two file operations of a save leaves
the old checkpoint or the new one; damaged or mismatched files are refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file

from model.checkpoint import (
    FILE,
    LEGACY_FORMAT,
    STATE,
    TENSORS,
    load_checkpoint,
    read_meta,
    save_steps,
)
from model.train_step import TrainConfig, Trainer
from schemas.errors import DataError
from tests.model.model_fixtures import make_batch, tiny_cfg


def _trainer(steps: int) -> Trainer:
    tr = Trainer(tiny_cfg("geom_only"), TrainConfig(lr=1e-3, seed=0))
    for i in range(steps):
        b = make_batch(B=2, V=3, seed=i)
        del b["h"]
        tr.step(b)
    return tr


@pytest.fixture(scope="module")
def old_new() -> tuple[Trainer, Trainer]:
    return _trainer(2), _trainer(4)


def test_a_kill_between_any_two_operations_leaves_old_or_new(tmp_path: Path,
                                                             old_new: tuple) -> None:
    old, new = old_new
    n_ops = len(save_steps(tmp_path / "probe", *new.state()))
    assert n_ops >= 5
    outcomes = []
    for cut in range(n_ops + 1):  # run the first `cut` operations, then "die"
        ck = tmp_path / f"cut{cut}"
        old.save(ck)
        for _name, op in save_steps(ck, *new.state())[:cut]:
            op()
        resumed = Trainer.load(ck)  # never a mix: the hash and the step are checked
        assert resumed.step_count in (2, 4)
        ref = old if resumed.step_count == 2 else new
        for p, q in zip(ref.net.parameters(), resumed.net.parameters(), strict=True):
            assert torch.equal(p.detach(), q.detach())
        resumed.save(ck)  # and the next save completes over whatever was left
        assert read_meta(ck)["step"] == resumed.step_count
        assert [p.name for p in ck.iterdir()] == [FILE]
        outcomes.append(resumed.step_count)
    assert outcomes[0] == 2 and outcomes[-1] == 4  # both sides of the rename were cut


def test_a_save_killed_mid_write_leaves_the_old_one(tmp_path: Path, old_new: tuple) -> None:
    old, new = old_new
    old.save(tmp_path)
    new.save(tmp_path / "whole")
    data = (tmp_path / "whole" / FILE).read_bytes()
    (tmp_path / f".{FILE}.999.tmp").write_bytes(data[: len(data) // 2])  # cut mid-write
    assert Trainer.load(tmp_path).step_count == 2


def test_damaged_tensors_are_refused_in_one_line(tmp_path: Path, old_new: tuple) -> None:
    old, _ = old_new
    old.save(tmp_path)
    raw = bytearray((tmp_path / FILE).read_bytes())
    raw[-100] ^= 0x01  # a flipped low bit in the last tensor's data
    (tmp_path / FILE).write_bytes(bytes(raw))
    with pytest.raises(DataError, match="SHA-256") as info:
        load_checkpoint(tmp_path)
    assert "\n" not in str(info.value) and str(tmp_path) in str(info.value)


def test_a_mismatched_format_1_pair_is_refused_in_one_line(tmp_path: Path,
                                                           old_new: tuple) -> None:
    """Format 1 wrote tensors.safetensors, then state.json: a kill between the two left the
    tensors of one step beside the state of another."""
    old, new = old_new
    tensors_new, _ = new.state()
    _, meta_old = old.state()
    save_file({k: v.contiguous() for k, v in tensors_new.items()}, str(tmp_path / TENSORS))
    (tmp_path / STATE).write_text(json.dumps({**meta_old, "format": LEGACY_FORMAT}))
    with pytest.raises(DataError) as info:
        Trainer.load(tmp_path)
    msg = str(info.value)
    assert "\n" not in msg and "optimizer step 4" in msg and "step 2" in msg


def test_a_matching_format_1_pair_still_loads(tmp_path: Path, old_new: tuple) -> None:
    old, _ = old_new
    tensors, meta = old.state()
    save_file({k: v.contiguous() for k, v in tensors.items()}, str(tmp_path / TENSORS))
    (tmp_path / STATE).write_text(json.dumps({**meta, "format": LEGACY_FORMAT}))
    assert Trainer.load(tmp_path).step_count == 2
    old.save(tmp_path)  # rewritten as format 2, the pair removed
    assert sorted(p.name for p in tmp_path.iterdir()) == [FILE]
    assert load_file(str(tmp_path / FILE)).keys() == tensors.keys()


def test_the_safetensors_writers_own_temporary_is_recognised(tmp_path: Path) -> None:
    """Was: a first save killed inside `save_file` left safetensors' `.tmpXXXXXX`, which the
    recovery did not know, so --resume, a plain rerun and --force all refused the folder."""
    from model.checkpoint import remove_temporaries, temporaries

    (tmp_path / ".tmpAb12Cd").write_bytes(b"\0" * 64)
    (tmp_path / f".{FILE}.4242.tmp").write_bytes(b"\0" * 32)
    (tmp_path / ".tmp_notes").write_text("not a writer's temporary")
    (tmp_path / ".tmpfolder").mkdir()
    assert [p.name for p in temporaries(tmp_path)] == [f".{FILE}.4242.tmp", ".tmpAb12Cd"]
    assert remove_temporaries(tmp_path) == 96
    assert sorted(p.name for p in tmp_path.iterdir()) == [".tmp_notes", ".tmpfolder"]


def test_the_writers_temporary_has_the_name_recognised(tmp_path: Path) -> None:
    """safetensors writes beside its file under a `.tmpXXXXXX` name (watched while it
    writes 8 MB); skipped where the write was too quick to be seen."""
    import threading

    from model.checkpoint import WRITER_TEMP

    seen: set[str] = set()
    done = threading.Event()

    def watch() -> None:
        while not done.is_set():
            seen.update(p.name for p in tmp_path.iterdir())

    watcher = threading.Thread(target=watch)
    watcher.start()
    save_file({"a": torch.zeros(2_000_000)}, str(tmp_path / "x.safetensors"))
    done.set()
    watcher.join()
    others = seen - {"x.safetensors"}
    if not others:
        pytest.skip("no temporary seen during the write")
    assert all(WRITER_TEMP.fullmatch(name) for name in others), others
