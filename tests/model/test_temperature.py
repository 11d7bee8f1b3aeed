"""The sampler temperature's choice, its checkpoint record and the default sample/eval take."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from model.checkpoint import load_checkpoint, read_meta
from model.temperature import (
    SAMPLER_KEY,
    SAMPLER_VERSION,
    Choice,
    choose_temperature,
    pick,
    record_sampler,
    recorded_temperature,
    resolve_temperature,
    val_recordings,
)
from model.train_step import TrainConfig, Trainer
from schemas.errors import DataError
from tests.model.model_fixtures import make_batch, tiny_cfg

CHOICE = Choice(steps=10, guidance=1.0, clips=4, batch_size=2, seed=0)


def test_pick_takes_the_best_psnr_and_the_lowest_temperature_on_a_tie() -> None:
    assert pick({0.0: 14.0, 0.5: 15.0, 1.0: 13.0}) == 0.5
    assert pick({1.0: 15.0, 0.25: 15.0, 0.5: 14.0}) == 0.25
    with pytest.raises(ValueError, match="no temperature"):
        pick({})


def test_bench_pick_is_the_model_pick() -> None:
    from bench.science_tempered import pick as bench_pick

    for val in ({0.0: 1.0, 1.0: 2.0}, {0.0: 2.0, 0.5: 2.0}):
        assert bench_pick(val) == pick(val)


def test_val_recordings_are_a_fixed_draw_leaving_one_to_train() -> None:
    names = ["c", "a", "b", "a", "d"]
    held = val_recordings(names, 2)
    assert held == val_recordings(list(reversed(names)), 2) == sorted(held)
    assert len(held) == 2 and set(held) < {"a", "b", "c", "d"}
    for n in (0, 4):
        with pytest.raises(DataError, match="4 recording"):
            val_recordings(names, n)


def test_choose_temperature_scores_every_temperature_and_records_the_pick() -> None:
    seen: list[float] = []

    def score(t: float) -> tuple[float, int]:
        seen.append(t)
        return 15.0 - (t - 0.5) ** 2, 3

    block = choose_temperature(score, CHOICE, ["r1"])
    assert seen == [0.0, 0.25, 0.5, 1.0]
    assert block == {"version": SAMPLER_VERSION, "temperature": 0.5, "steps": 10,
                     "guidance": 1.0, "recordings": ["r1"], "clips": 3,
                     "val_psnr": {"0": 14.75, "0.25": 14.9375, "0.5": 15.0, "1": 14.75}}


def _checkpoint(tmp_path: Path) -> Path:
    tr = Trainer(tiny_cfg("full"), TrainConfig(lr=1e-3, seed=0))
    tr.step(make_batch())
    tr.save(tmp_path / "ck", extra={"stream": {"epoch": 1}})
    return tmp_path / "ck"


def test_record_sampler_keeps_the_tensors_and_the_state(tmp_path: Path) -> None:
    ck = _checkpoint(tmp_path)
    before_t, before = load_checkpoint(ck)
    assert recorded_temperature(before) is None
    block = {"version": SAMPLER_VERSION, "temperature": 0.25, "steps": 10, "guidance": 1.0,
             "val_psnr": {"0.25": 15.0}, "recordings": ["r1"], "clips": 2}
    record_sampler(ck, block)
    after_t, after = load_checkpoint(ck)  # hash checked
    assert after[SAMPLER_KEY] == block and recorded_temperature(after) == 0.25
    assert {k: v for k, v in after.items() if k != SAMPLER_KEY} == before
    assert after_t.keys() == before_t.keys()
    assert all(torch.equal(after_t[k], before_t[k]) for k in before_t)
    back = Trainer.load(ck)  # a recorded checkpoint still resumes
    assert back.step_count == 1 and back.extra == {"stream": {"epoch": 1}}
    assert read_meta(ck)[SAMPLER_KEY]["temperature"] == 0.25


def test_a_sampler_block_of_another_version_is_not_read() -> None:
    assert recorded_temperature({SAMPLER_KEY: {"version": 99, "temperature": 0.0}}) is None
    assert recorded_temperature({SAMPLER_KEY: "0.5"}) is None


META = {SAMPLER_KEY: {"version": SAMPLER_VERSION, "temperature": 0.25, "steps": 10,
                      "recordings": ["r1", "r2"]}}


def test_resolve_order_explicit_config_checkpoint_paper() -> None:
    assert resolve_temperature(1.0, 0.5, META) == (1.0, "--temperature", None)
    assert resolve_temperature(None, 0.5, META) == (0.5, "config sample.temperature", None)
    t, where, note = resolve_temperature(None, None, META)
    assert (t, note) == (0.25, None)
    assert "2 validation recording(s) at K=10" in where
    t, where, note = resolve_temperature(None, None, {})
    assert t == 1.0 and "records none" in where
    assert note is not None and "--temperature" in note
