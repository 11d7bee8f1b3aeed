"""The camera rig in config: any names, each camera's own topics and frame."""

from __future__ import annotations

import pytest

from schemas.config import (
    CameraTopics,
    HfConfig,
    IngestConfig,
    M3GDConfig,
    SynthConfig,
    TopicsConfig,
    config_to_dict,
)


def test_templates_are_the_default_and_a_camera_may_have_its_own() -> None:
    t = TopicsConfig(per_camera={"cam1": CameraTopics(image="/a/img", frame="cam1_optical")})
    assert t.image_topic("cam1") == "/a/img"
    assert t.info_topic("cam1") == "/boxi/hdr/cam1/camera_info"  # unset key: the template
    assert t.frame_of("cam1") == "cam1_optical"
    assert t.image_topic("front") == "/boxi/hdr/front/image_raw/compressed"
    assert t.frame_of("front") == "hdr_front"
    assert HfConfig(camera_groups={"x": "zed_left"}).group("x") == "zed_left"
    assert HfConfig().group("x") == "hdr_x"


def test_unset_overrides_leave_the_serialized_config_as_before() -> None:
    data = config_to_dict(M3GDConfig())
    assert "per_camera" not in data["ingest"]["topics"]
    assert "camera_groups" not in data["ingest"]["hf"]
    own = IngestConfig(cameras=["a"], topics=TopicsConfig(per_camera={"a": {"image": "/x"}}))
    assert config_to_dict(own)["topics"]["per_camera"] == {
        "a": {"image": "/x", "info": None, "frame": None}}


def test_any_camera_names_are_accepted() -> None:
    cams = [f"alphasense_{i}" for i in range(8)] + ["zed2i_left", "zed2i_right"]
    assert IngestConfig(cameras=cams).cameras == cams
    assert SynthConfig(cameras=["alphasense_front_left"]).cameras == ["alphasense_front_left"]


@pytest.mark.parametrize(("cfg", "match"), [
    ({"cameras": ["a/b"]}, "camera name 'a/b'"),
    ({"cameras": ["a", "a"]}, "camera 'a' is listed twice"),
    ({"cameras": ["a"], "topics": {"per_camera": {"b": {"image": "/x"}}}},
     "per_camera names camera 'b'"),
    ({"cameras": ["a", "b"], "topics": {"per_camera": {"a": {"image": "/x"},
                                                      "b": {"image": "/x"}}}},
     "share the image topic '/x'"),
])  # fmt: skip
def test_a_rig_that_cannot_work_is_refused_in_one_line(cfg: dict[str, object],
                                                       match: str) -> None:  # fmt: skip
    with pytest.raises(ValueError, match=match):
        IngestConfig.model_validate(cfg)
