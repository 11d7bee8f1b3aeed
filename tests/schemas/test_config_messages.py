"""Configuration errors: every bad key at once, in one line, with a did-you-mean."""

from __future__ import annotations

from pathlib import Path

import pytest

from schemas.config import ConfigError, M3GDConfig, load_config, parse_config


def test_every_error_is_reported_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("ingest:\n  topic: {lidar: /x}\nsample: {guidanse: 2}\n"
                    "synth: {seconds: -1}\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{path}: ")
    assert "unknown key 'ingest.topic' (value {'lidar': '/x'}) (did you mean " \
           "'ingest.topics'?)" in msg
    assert "unknown key 'sample.guidanse' (value 2) (did you mean 'sample.guidance'?)" in msg
    assert "bad value for 'synth.seconds': -1" in msg
    assert msg.count("; ") == 2


def test_no_suggestion_for_a_key_unlike_any() -> None:
    with pytest.raises(ConfigError) as info:
        parse_config({"dag": {"zzzzzz": 1}})
    assert str(info.value) == "<config>: unknown key 'dag.zzzzzz' (value 1)"


def test_unknown_top_level_section_gets_a_suggestion() -> None:
    with pytest.raises(ConfigError, match=r"unknown key 'packet' \(value \{\}\) \(did you mean "
                                          r"'packets'\?\)$"):
        parse_config({"packet": {}})


def test_every_key_has_a_description() -> None:
    from docs_gen.config_ref import key_rows, sections

    missing = [row[0] for path, model in sections() for row in key_rows(model, path)
               if not model.model_fields[row[0].rsplit(".", 1)[-1]].description]
    assert missing == []


def test_train_defaults_are_the_science_bench_recipe() -> None:
    from bench.science import FULL, train_config

    t, spec = M3GDConfig().train, FULL.spec
    assert t.ema_decay == train_config(spec, seed=0).ema_decay
    assert (t.steps, t.batch_size, t.lr, t.warmup_steps, t.lr_min) == (
        spec.steps, spec.batch_size, spec.lr, spec.warmup_steps, spec.lr_min)
    assert t.patch == spec.patch and t.preset == "tiny"
    assert M3GDConfig().sample.guidance == spec.guidance
