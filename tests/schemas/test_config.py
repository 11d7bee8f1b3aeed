"""Config validation: defaults, one-line errors naming file, key and value."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.app import app
from schemas.config import (
    ConfigError,
    M3GDConfig,
    config_hash,
    config_to_dict,
    key_dict,
    load_config,
    parse_config,
)


def test_defaults_are_the_paper_sizes() -> None:
    cfg = M3GDConfig()
    assert (cfg.ingest.out_height, cfg.ingest.out_width) == (224, 336)
    assert cfg.select.max_abs_dt_s == 0.1
    assert cfg.encoders.point_channels == 1224


def _load_error(tmp_path: Path, text: str) -> tuple[Path, str]:
    """(config path, the ConfigError message) of loading `text` as a config file."""
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return path, str(info.value)


def test_unknown_key_names_file_key_value(tmp_path: Path) -> None:
    path, msg = _load_error(tmp_path, "ingest:\n  bogus: 3\n")
    assert str(path) in msg and "ingest.bogus" in msg and "3" in msg
    assert "\n" not in msg


def test_bad_value_names_key_and_value(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("select:\n  max_abs_dt_s: -0.5\n")
    with pytest.raises(ConfigError, match=r"select\.max_abs_dt_s.*-0\.5"):
        load_config(path)


def test_image_size_must_be_patch_multiple() -> None:
    with pytest.raises(ConfigError, match="out_width"):
        parse_config({"ingest": {"out_width": 300}})


def test_unknown_config_version_refused() -> None:
    with pytest.raises(ConfigError, match="version"):
        parse_config({"version": 99})


def test_hash_changes_with_content() -> None:
    a = parse_config({})
    b = parse_config({"select": {"max_abs_dt_s": 0.05}})
    assert config_hash(a) == config_hash(parse_config({}))
    assert config_hash(a) != config_hash(b)


def test_cli_bad_config_exits_2(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("cache:\n  shard_views: zero\n")
    result = CliRunner().invoke(app, ["--config", str(path), "config", "show"])
    assert result.exit_code == 2
    assert "cache.shard_views" in result.output and "zero" in result.output


def test_cli_config_show_round_trips(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("select:\n  max_abs_dt_s: 0.07\n")
    result = CliRunner().invoke(app, ["--config", str(path), "config", "show"])
    assert result.exit_code == 0, result.output
    shown = tmp_path / "shown.yaml"
    shown.write_text(result.stdout)
    assert load_config(shown) == load_config(path)


def test_yaml_syntax_error_names_line_and_column(tmp_path: Path) -> None:
    path, msg = _load_error(tmp_path, "select:\n  max_abs_dt_s: 0.1\ningest: out_width: 336\n")
    assert msg.startswith(f"{path}:3:") and "not valid YAML" in msg and "\n" not in msg


def test_recordings_with_one_folder_name_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"^<config>: bad value in 'ingest': recordings share "
                                          r"the folder name 'm1': /a/m1, /b/m1$"):
        parse_config({"ingest": {"recordings": ["/a/m1", "/b/m1"]}})


def test_devices_and_precisions_are_checked() -> None:
    cfg = parse_config({"train": {"device": "cuda:1", "precision": "bf16"},
                        "encoders": {"device": "mps"}})
    assert cfg.train.device == "cuda:1" and cfg.encoders.device == "mps"
    for bad in ({"train": {"device": "gpu"}}, {"train": {"device": "cuda:x"}},
                {"train": {"precision": "fp8"}}, {"encoders": {"worker_resources": "GPU"}}):
        with pytest.raises(ConfigError):
            parse_config(bad)


def test_where_encoders_run_is_not_part_of_their_cache_key() -> None:
    base = parse_config({})
    moved = parse_config({"encoders": {"device": "cuda", "worker_resources": "GPU=1"}})
    other = parse_config({"encoders": {"seed": 1}})
    assert key_dict(base.encoders) == key_dict(moved.encoders)
    assert key_dict(base.encoders) != key_dict(other.encoders)
    assert "device" in config_to_dict(moved.encoders)  # still shown by `m3gd config show`
