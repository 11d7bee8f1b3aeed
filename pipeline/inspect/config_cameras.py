"""The camera keys of a configuration written from an inspection.

Every camera with a calibration, a frame and a readable image is configured, under a name of
its own. Three ways, most compact first:

1. the cameras fit one `{camera}` template with the default names (front, left, right;
   GrandTour's layout): the template keys, no per-camera keys;
2. each camera is named after its image topic (`camera_names`: the topic's last two segments
   that name something, `/boxi/hdr/front/image_raw/compressed` -> `hdr_front`,
   `/gt_box/zed2i/zed_node/left/image_rect_color/compressed` -> `zed2i_left`; a namespace every
   camera shares left out), and all of them fit one template with those names: the template
   keys;
3. otherwise each camera's own image topic, info topic and frame (`topics.per_camera`; in the
   Hugging Face layout its store group, `hf.camera_groups`, and its frame).

Raw `sensor_msgs/Image` and PNG cameras are configured like JPEG ones (ingest reads them);
a camera whose CameraInfo changes is configured and told (each image follows the CameraInfo
in force at its stamp).
"""

from __future__ import annotations

import re
import typing
from dataclasses import dataclass, field
from typing import Any

from pipeline.inspect.model import CameraReport
from schemas.config import CameraName
from schemas.names import name_problem

NAMES: tuple[str, ...] = typing.get_args(CameraName)
FRAME_SUFFIXES = ("_optical_frame", "_optical", "_sensor_frame", "_sensor", "_frame", "_link")
"""Frame-name endings that say what kind of frame it is, not which camera (dropped)."""
GENERIC_SEGMENTS = frozenset({"", "image", "image_raw", "image_rect", "image_rect_color",
                              "image_color", "compressed", "color", "rgb", "raw", "camera"})
"""Topic segments that name no camera (skipped when a name comes from the topic)."""
DRIVER_SUFFIXES = ("_driver_node", "_driver", "_node", "_ros")
"""Topic-segment endings of a driver's node (`alphasense_driver_node` -> `alphasense`)."""
NAME_SEGMENTS = 2
"""A camera's name joins this many of its topic's last naming segments (the family and the
camera: `hdr_front`, not `front`, which another family's camera may also be)."""


@dataclass
class CameraKeys:
    """The camera keys decided: names in order, `topics` template keys, `per_camera` keys,
    `hf` keys (template or `camera_groups`), and the lines told to the user."""

    names: list[str] = field(default_factory=list)
    topics: dict[str, Any] = field(default_factory=dict)
    hf: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def _template(value: str, name: str) -> str | None:
    """`value` with `name` replaced by `{camera}` (None when `name` is not in it or the value
    holds braces)."""
    if name not in value or "{" in value or "}" in value:
        return None
    return value.replace(name, "{camera}")


def _parts(cam: CameraReport, hf: bool) -> list[str]:
    """The values a template must give for `cam`: image topic (or group), info topic, frame."""
    return [cam.image_topic] + ([] if hf else [cam.info_topic or ""]) + [cam.frame_id]


def _keys(hf: bool) -> tuple[str, ...]:
    return ("camera_group", "camera_frame") if hf else ("camera_image", "camera_info",
                                                       "camera_frame")


def camera_templates(cams: list[CameraReport], hf: bool) -> tuple[dict[str, str], list[str]]:
    """(template keys, camera names) of the largest set of cameras sharing one template with
    the default names (front, left, right); ({}, []) when none fits one.

    Keys: camera_image, camera_info, camera_frame (bags) or camera_group, camera_frame (hf).
    """
    groups: dict[tuple[str, ...], list[str]] = {}
    for cam in cams:
        for name in NAMES:
            tpl = [_template(p, name) for p in _parts(cam, hf)]
            if all(t is not None for t in tpl):
                groups.setdefault(tuple(typing.cast(list[str], tpl)), []).append(name)
    if not groups:
        return {}, []
    key, names = max(groups.items(), key=lambda kv: (len(set(kv[1])), kv[0]))
    return dict(zip(_keys(hf), key, strict=True)), sorted(set(names), key=NAMES.index)


def topic_segments(topic: str) -> list[str]:
    """The segments of an image topic that name something: generic ones (`image_raw`,
    `compressed`, ...) dropped, a driver node's suffix (`_driver_node`, `_node`) removed, a
    segment the previous one starts with dropped (`zed2i/zed_node` -> `zed2i`)."""
    out: list[str] = []
    for seg in topic.split("/"):
        for suffix in DRIVER_SUFFIXES:
            if seg.endswith(suffix) and len(seg) > len(suffix):
                seg = seg.removesuffix(suffix)
                break
        if seg.lower() in GENERIC_SEGMENTS or seg in ("driver", "node"):
            continue
        if out and out[-1].startswith(seg):
            continue
        out.append(seg)
    return out


def _clean(name: str) -> str:
    """`name` as a camera name: other characters as `_`, no leading `_` or `.`."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name).lstrip("_.")


def _frame_name(cam: CameraReport) -> str:
    """A name from the camera's frame without a kind suffix (`zed2i_left_optical` ->
    `zed2i_left`); '' when none is left."""
    frame = cam.frame_id.strip("/").replace("/", "_")
    for suffix in FRAME_SUFFIXES:
        if frame.endswith(suffix) and len(frame) > len(suffix):
            frame = frame.removesuffix(suffix)
            break
    return frame if frame and name_problem(frame) is None and not frame.startswith("_") else ""


def camera_names(cams: list[CameraReport]) -> list[str]:
    """Each camera's name after its image topic (module docstring): the last NAME_SEGMENTS
    naming segments once the leading ones every camera shares (with two or more) are left
    out; a topic naming nothing takes its frame's name, else `camera`; numbered when taken."""
    segs = [topic_segments(c.image_topic) for c in cams]
    shared = 0
    if len(segs) > 1:
        while all(len(s) > shared + 1 for s in segs) and len({s[shared] for s in segs}) == 1:
            shared += 1
    names = [_clean("_".join(s[shared:][-NAME_SEGMENTS:])) or _frame_name(c) or "camera"
             for s, c in zip(segs, cams, strict=True)]  # fmt: skip
    return _unique(names)


def camera_name(cam: CameraReport) -> str:
    """The name of a camera alone (`camera_names` of it)."""
    return camera_names([cam])[0]


def _unique(names: list[str]) -> list[str]:
    """`names` with a repeated one numbered (`cam`, `cam_2`, ...)."""
    out: list[str] = []
    for n in names:
        name, i = n, 2
        while name in out:
            name, i = f"{n}_{i}", i + 1
        out.append(name)
    return out


def camera_keys(cameras: tuple[CameraReport, ...], hf: bool) -> CameraKeys:
    """The camera keys of a configuration for `cameras` (see the module docstring)."""
    keys = CameraKeys()
    usable = [c for c in cameras if c.calibrations and c.frame_id and c.error is None]
    for c in cameras:
        if c not in usable:
            keys.warnings.append(f"camera {c.image_topic}: left out (no calibration, frame or "
                                 f"readable image{': ' + c.error if c.error else ''})")
    if not usable:
        keys.warnings.append("no camera could be configured")
        return keys
    tpl, names = camera_templates(usable, hf)
    if len(names) == len(usable):  # every camera, by the default names
        keys.names = names
    else:
        names = camera_names(usable)
        tpl = _shared_template(usable, names, hf)
        keys.names = names
        if not tpl:
            _per_camera(usable, names, hf, keys)
    _put_template(tpl, hf, keys)
    for c in usable:
        if c.calibration_changes:
            keys.warnings.append(f"camera {c.image_topic}: its camera_info changes during the "
                                 "recording; each image follows the CameraInfo in force at "
                                 "its stamp")
    return keys


def _shared_template(cams: list[CameraReport], names: list[str], hf: bool) -> dict[str, str]:
    """The template keys every camera fits under its own name ({} when they fit none; a
    single camera is always written with its own keys)."""
    if len(cams) < 2:
        return {}
    tpls = {tuple(_template(p, n) for p in _parts(c, hf)) for c, n in zip(cams, names,
                                                                          strict=True)}
    if len(tpls) != 1:
        return {}
    (tpl,) = tpls
    if any(t is None for t in tpl):
        return {}
    return dict(zip(_keys(hf), typing.cast(tuple[str, ...], tpl), strict=True))


def _put_template(tpl: dict[str, str], hf: bool, keys: CameraKeys) -> None:
    """Template keys into the topics (frame, bag topics) and hf (group) sections."""
    for k, v in tpl.items():
        (keys.hf if k == "camera_group" else keys.topics)[k] = v


def _per_camera(cams: list[CameraReport], names: list[str], hf: bool, keys: CameraKeys) -> None:
    """Each camera's own topics (or group) and frame."""
    own: dict[str, dict[str, str]] = {}
    groups: dict[str, str] = {}
    for c, n in zip(cams, names, strict=True):
        if hf:
            groups[n] = c.image_topic
            own[n] = {"frame": c.frame_id}
        else:
            own[n] = {"image": c.image_topic, "info": c.info_topic or "", "frame": c.frame_id}
    keys.topics["per_camera"] = own
    if groups:
        keys.hf["camera_groups"] = groups
