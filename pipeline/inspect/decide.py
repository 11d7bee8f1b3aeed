"""Inspect's decisions about the rig, from evidence, each with its alternatives (pure).

- `decide_pose`: where the robot's pose comes from. REP 105 semantics: the world frames are
  `map`, `odom`, `world`, `earth` (and names made of them, `odom_combined`); the body frame
  is the frame the sensors hang off; the pose is the moving edge between a world frame and
  the body, in either direction (GrandTour publishes `odom` as a child of `base`). Joints
  and wheels (`robot_state_publisher`) are moving edges too, but they hang off the body: no
  sensor is reached through them, their far frame is no world frame, their translation does
  not change. `map -> odom` (localization) jumps; its near end is itself a world frame. An
  odometry topic is explicit and preferred; its agreement with the /tf edge between the same
  frames is evidence, its disagreement makes the decision ambiguous.
- `decide_lidars`: the reference LiDAR (most messages, then rate, then name); a topic without
  messages or whose clouds cannot be read is named and left out.
- `decide_camera`: a camera's frame: the image's frame_id, its CameraInfo's, whichever the TF
  tree reaches from the body.

Every candidate carries the configuration keys it implies and its evidence in short phrases;
a decision is `ambiguous` when the evidence does not separate the best two (the chosen one is
still the first by score, then by the order candidates were found).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import replace

import numpy as np
import numpy.typing as npt

from packets.poses import invert_T
from pipeline.inspect.model import (
    Agreement,
    CameraReport,
    Candidate,
    CloudReport,
    Decision,
    TfEdge,
    TfReport,
)

F64 = npt.NDArray[np.float64]
WORLD_NAMES = ("map", "odom", "world", "earth")
"""REP 105's fixed frames; a frame whose name is one of them or holds one as a `_` part."""
JOINT_WORDS = frozenset({"wheel", "joint", "leg", "arm", "caster", "finger", "gripper", "thigh",
                         "shank", "hip", "knee", "foot", "pan", "tilt", "spinner", "track",
                         "flipper", "hfe", "kfe", "haa"})  # fmt: skip
"""Name parts of frames that move with a joint (wheels, legs, heads)."""
AGREE_M = 0.05
"""Odometry and /tf agree when their relative motions differ by at most this (m) or 5 %."""
JUMP_M = 0.25
"""A step of a moving edge longer than this (m) between two samples is a jump."""
MOVES_M = 0.05
"""A moving edge whose translation travels more than this (m) over the sample moves."""
TIE = 0.5
"""Candidates whose scores differ by less than this are not separated by the evidence."""


def is_world(frame: str) -> bool:
    """Whether `frame` names a REP 105 world frame (`map`, `odom`, `odom_combined`, ...)."""
    parts = re.split(r"[^a-z]+", frame.lower())
    return any(p in WORLD_NAMES for p in parts)


def is_joint(frame: str) -> bool:
    """Whether `frame` is named like a joint or a wheel."""
    return any(p in JOINT_WORDS for p in re.split(r"[^a-z]+", frame.lower()))


def _adjacency(edges: Iterable[TfEdge], without: TfEdge | None = None) -> dict[str, set[str]]:
    """Undirected neighbours of every frame (one edge left out)."""
    adj: dict[str, set[str]] = {}
    for e in edges:
        adj.setdefault(e.parent, set())
        adj.setdefault(e.child, set())
        if e is not without:
            adj[e.parent].add(e.child)
            adj[e.child].add(e.parent)
    return adj


def component(adj: dict[str, set[str]], start: str) -> set[str]:
    """The frames connected to `start` (itself included)."""
    seen, todo = {start}, [start]
    while todo:
        for n in adj.get(todo.pop(), ()):
            if n not in seen:
                seen.add(n)
                todo.append(n)
    return seen


def static_component(tf: TfReport, frame: str) -> set[str]:
    """The frames the static edges connect to `frame`."""
    return component(_adjacency(e for e in tf.edges if e.static), frame)


def body_root(tf: TfReport, frame: str) -> str:
    """The root of the static tree holding `frame` (else the tree's only root), or ''."""
    children = {e.child for e in tf.edges if e.static}
    if any(frame in (e.parent, e.child) for e in tf.edges if e.static):
        roots = sorted(f for f in static_component(tf, frame) if f not in children)
        if len(roots) == 1:
            return roots[0]
    return tf.roots[0] if len(tf.roots) == 1 else ""


def _edge_candidate(tf: TfReport, e: TfEdge, sensors: set[str]) -> Candidate | None:
    """A moving edge as the pose source, with its evidence; None for an edge in a cycle."""
    adj = _adjacency(tf.edges, without=e)
    near, far = component(adj, e.parent), component(adj, e.child)
    if e.child in near:
        return None
    s_parent, s_child = sensors & near, sensors & far
    ev: list[str] = []
    score = 0.0
    if bool(s_parent) != bool(s_child):
        body, world = (e.parent, e.child) if s_parent else (e.child, e.parent)
        ev.append(f"{len(s_parent or s_child)} sensor frame(s) reached through {body}")
        score += 4
    else:
        body, world = ((e.child, e.parent) if is_world(e.parent) or not is_world(e.child)
                       else (e.parent, e.child))  # fmt: skip
        ev.append("sensors on both sides" if s_parent else "no sensor reached through it")
    far_side = far if world == e.child else near
    worlds = sorted(f for f in far_side if is_world(f))
    if worlds:
        ev.append(f"world frame {', '.join(worlds)} beyond it")
        score += 3
    else:
        ev.append("no map/odom/world frame beyond it")
    if is_world(body):
        ev.append(f"its body end {body} is itself a world frame")
        score -= 3
    if is_joint(world):
        ev.append(f"{world} is named as a joint or wheel")
        score -= 3
    if e.messages > 1 and e.travel_m > MOVES_M:
        ev.append(f"moves {e.travel_m:.2f} m in {e.messages} samples")
        score += 1
    elif e.messages > 1 and e.travel_m < 1e-3:
        ev.append("its translation does not change (a joint turning in place)")
        score -= 1
    if e.jump_m > JUMP_M:
        ev.append(f"jumps {e.jump_m:.2f} m in one step (localization)")
        score -= 2
    ev.append(f"{e.rate_hz:.4g} Hz" if e.rate_hz else f"{e.messages} sample(s)")
    ev.append("REP 105 direction" if world == e.parent else "published body -> world")
    keys = {"tf": e.topic, "odom_frame": world, "base_frame": body}
    return Candidate(f"{e.topic} {e.parent}->{e.child}", keys, tuple(ev), score)


def _topic_candidate(tf: TfReport, odo: tuple[str, str, str], msgtype: str, root: str,
                     sensors: set[str], agreement: Sequence[Agreement]) -> Candidate:  # fmt: skip
    """An odometry topic as the pose source, with its evidence."""
    topic, frame, child = odo
    base = child or root
    ev = [f"odometry topic ({msgtype.split('/')[-1] or '?'})"]
    score = 5.0 if child else 4.5  # declared odometry: above any /tf edge's evidence (8)
    if not child:
        ev.append(f"no child frame: the static root {root or '?'} of the LiDAR's tree")
    frames = set(tf.frames)
    if base and base in frames and sensors & component(_adjacency(tf.edges), base):
        ev.append(f"sensor frames reached through {base}")
        score += 4
    elif base and base not in frames:
        ev.append(f"{base} is not in the TF tree")
        score -= 2
    for a in agreement:
        if a.topic == topic:
            tol = max(AGREE_M, 0.05 * a.travel_m)
            verdict = "agrees with" if a.error_m <= tol else "DISAGREES with"
            ev.append(f"{verdict} {a.edge} ({a.error_m:.3f} m over {a.travel_m:.2f} m, "
                      f"{a.samples} stamps)")
    keys = {"odometry": topic, "odom_frame": frame or "odom"} | ({"base_frame": base} if base
                                                                 else {})  # fmt: skip
    return Candidate(topic, keys, tuple(ev), score)


def _ranked(what: str, cands: list[Candidate], viable: set[str], pick: str) -> Decision:
    """A decision over `cands` (the viable ones by score, stable; the rest after them):
    ambiguous when the best two viable are within TIE."""
    good = sorted((c for c in cands if c.name in viable), key=lambda c: -c.score)
    rest = [c for c in cands if c.name not in viable]
    if not good:
        return Decision(what, "", tuple(rest), False, f"no candidate: {pick}")
    best = good[0]
    close = [c for c in good[1:] if best.score - c.score < TIE]
    why = "; ".join(best.evidence[:3])
    others = len(cands) - 1
    tail = f"; {others} alternative(s)" if others else ""
    if close:
        return Decision(what, best.name, tuple(good + rest), True,
                        f"{best.name} and {close[0].name} are not told apart by the evidence "
                        f"({why}); the first taken")  # fmt: skip
    return Decision(what, best.name, tuple(good + rest), False, f"{why}{tail}")


def decide_pose(tf: TfReport, odometry: Sequence[tuple[str, str, str]], types: dict[str, str],
                sensors: Iterable[str], root: str = "",
                agreement: Sequence[Agreement] = ()) -> Decision:  # fmt: skip
    """The pose source: an odometry topic (`odometry`: (topic, frame, child) each; `types`:
    topic -> message type) or a moving /tf edge, among every candidate with its evidence.
    `sensors`: the LiDAR and camera frames; `root`: the LiDAR's static root (the body of a
    pose message without child frame); `agreement`: odometry topics against /tf."""
    known = set(sensors) & set(tf.frames)
    edges = [c for e in tf.edges if not e.static
             if (c := _edge_candidate(tf, e, known)) is not None]  # fmt: skip
    topics = [_topic_candidate(tf, o, types.get(o[0], ""), root, known, agreement)
              for o in odometry]  # fmt: skip
    viable = {c.name for c in topics} | {c.name for c in edges if c.score >= 3}
    decision = _ranked("pose", topics + edges, viable,
                       "no odometry topic and no moving /tf edge between a world frame and the "
                       "body")  # fmt: skip
    chosen = next((c for c in decision.candidates if c.name == decision.chosen), None)
    if chosen is not None and any("DISAGREES" in ev for ev in chosen.evidence):
        bad = next(ev for ev in chosen.evidence if "DISAGREES" in ev)
        return replace(decision, ambiguous=True,
                       reason=f"odometry topic {chosen.name} {bad}: the topic taken; check "
                       "which estimator the packets should follow")  # fmt: skip
    return decision


def lidar_keys(cloud: CloudReport) -> dict[str, object]:
    """The `lidars:` entry of a cloud: topic, frame, point_time (its decided convention, else
    auto)."""
    conv = cloud.convention
    point_time: object = "auto"
    if cloud.time_field and conv.unit is not None and conv.reference is not None:
        point_time = {"field": cloud.time_field, "unit": conv.unit, "reference": conv.reference}
    return {"topic": cloud.topic, "frame": cloud.frame_id, "point_time": point_time}


def decide_lidars(clouds: Sequence[CloudReport], counts: dict[str, int],
                  rates: dict[str, float | None], body: set[str]) -> Decision:  # fmt: skip
    """The reference LiDAR and every other: the most messages first (then rate, then topic);
    a cloud without messages, without a frame or unreadable is a candidate left out.
    `body`: the frames connected to the body (empty: unknown)."""
    cands, viable = [], set()
    for c in sorted(clouds, key=lambda c: (-counts.get(c.topic, 0), -(rates.get(c.topic) or 0),
                                           c.topic)):  # fmt: skip
        n, rate = counts.get(c.topic, 0), rates.get(c.topic)
        ev = [f"{n} messages" + (f" at {rate:.4g} Hz" if rate else "")]
        if n == 0:
            ev = ["no messages (a topic declared, never written): left out"]
        elif c.error:
            ev.append(f"unreadable: {c.error}")
        elif not c.frame_id:
            ev.append("no frame_id: left out")
        else:
            viable.add(c.topic)
            ev.append(f"frame {c.frame_id}" + ("" if not body else " reached from the body"
                                                if c.frame_id in body
                                                else " not reached from the body"))  # fmt: skip
        cands.append(Candidate(c.topic, lidar_keys(c), tuple(ev), float(n) + (rate or 0) / 1e6,
                               c.topic in viable))  # fmt: skip
    good = [c for c in cands if c.name in viable]
    if not good:
        return Decision("lidar", "", tuple(cands), False, "no PointCloud2 topic with messages")
    best = good[0]
    tie = [c for c in good[1:] if c.score == best.score]
    order = tuple(good + [c for c in cands if c.name not in viable])
    if tie:
        return Decision("lidar", best.name, order, True, f"{best.name} and {tie[0].name} have "
                        "as many messages at the same rate; the first by name is the reference")
    why = f"reference {best.name}: the most messages ({best.evidence[0]})"
    if len(good) > 1:
        why += f"; {len(good) - 1} more declared, not merged"
    return Decision("lidar", best.name, order, False, why)


def decide_camera(cam: CameraReport, frames: set[str], body: set[str]) -> Decision:
    """A camera's frame: its image frame_id or its CameraInfo's, the one the TF tree (`frames`)
    holds, reached from the body (`body`) first; ambiguous when the two differ and the tree
    does not tell them apart."""
    names = list(dict.fromkeys(f for f in (cam.frame_id, cam.info_frame_id) if f))
    cands = []
    for f in names:
        ev = [("image frame_id" if f == cam.frame_id else "")
              + (" and " if f == cam.frame_id == cam.info_frame_id else "")
              + ("camera_info frame_id" if f == cam.info_frame_id else "")]
        score = 1.0 if f == cam.frame_id else 0.0
        if f in body:
            ev.append("reached from the body in the TF tree")
            score += 4
        elif f in frames:
            ev.append("in the TF tree, not reached from the body")
            score += 2
        else:
            ev.append("not in the TF tree")
        cands.append(Candidate(f, {"frame": f}, tuple(ev), score))
    what = f"camera {cam.image_topic}"
    if not cands:
        return Decision(what, "", (), False, "no frame_id on its images or camera_info")
    cands.sort(key=lambda c: -c.score)
    best = cands[0]
    if len(cands) == 1:
        return Decision(what, best.name, tuple(cands), False, "; ".join(best.evidence))
    split = best.score - cands[1].score >= 2
    reason = (f"image frame_id {cam.frame_id!r} and camera_info frame_id {cam.info_frame_id!r}"
              f" differ; {best.name} {best.evidence[1]}")
    return Decision(what, best.name, tuple(cands), not split,
                    reason + ("" if split else ": the image's taken"))


def relative_motion(stamps: Sequence[int], T: Sequence[F64], at: Sequence[int]) -> F64:
    """(K, 3) translation of the body's motion from `at[0]` to each stamp of `at` (ns; the
    nearest of `stamps`), in the body's frame at `at[0]`: independent of the world frame."""
    s = np.asarray(stamps, np.int64)
    idx = [int(np.abs(s - t).argmin()) for t in at]
    T0 = invert_T(T[idx[0]])
    return np.stack([(T0 @ T[i])[:3, 3] for i in idx])


def agreement_of(topic: str, edge: str, tf: tuple[Sequence[int], Sequence[F64]],
                 odo: tuple[Sequence[int], Sequence[F64]],
                 within_ns: int = 5_000_000) -> Agreement | None:  # fmt: skip
    """An odometry topic's T_odom_base samples (`odo`: stamps ns, (4, 4) each) against a /tf
    edge's, turned into T_odom_base (`tf`): over the odometry stamps that have a /tf sample
    within `within_ns`, the largest difference of the relative motions (m). None with fewer
    than two common stamps."""
    ts = np.asarray(tf[0], np.int64)
    if ts.size == 0:
        return None
    common = [int(t) for t in odo[0] if np.abs(ts - t).min() <= within_ns]
    if len(common) < 2:
        return None
    a = relative_motion(tf[0], tf[1], common)
    b = relative_motion(odo[0], odo[1], common)
    err = float(np.linalg.norm(a - b, axis=1).max())
    return Agreement(topic, edge, len(common), err, float(np.linalg.norm(b, axis=1).max()))


def decide_rig(tf: TfReport, odometry: Sequence[tuple[str, str, str]], types: dict[str, str],
               clouds: Sequence[CloudReport], cameras: Sequence[CameraReport],
               counts: dict[str, int], rates: dict[str, float | None],
               agreement: Sequence[Agreement] = ()) -> tuple[Decision, ...]:  # fmt: skip
    """Every decision of a recording: the pose source, the LiDARs, each camera's frame."""
    lidar_frames = [c.frame_id for c in sorted(clouds, key=lambda c: -counts.get(c.topic, 0))
                    if c.frame_id and counts.get(c.topic, 0) > 0]  # fmt: skip
    cam_frames = [f for c in cameras for f in (c.frame_id, c.info_frame_id) if f]
    root = body_root(tf, lidar_frames[0]) if lidar_frames else body_root(tf, "")
    pose = decide_pose(tf, odometry, types, lidar_frames + cam_frames, root, agreement)
    base = str(pose.keys.get("base_frame", root))
    body = static_component(tf, base) if base in tf.frames else set()
    lidar = decide_lidars(clouds, counts, rates, body)
    frames = set(tf.frames)
    return (pose, lidar, *(decide_camera(c, frames, body) for c in cameras))


def mismatches(decisions: Sequence[Decision], pose: dict[str, str], pose_ambiguous: bool,
               lidars: Sequence[str], camera_frames: dict[str, str]) -> list[str]:  # fmt: skip
    """How `decisions` differ from the expected ones, one line each (empty: they agree): the
    pose source's keys and ambiguity, the LiDARs declared (the reference first) and each
    camera's frame (by image topic)."""
    by = {d.what: d for d in decisions}
    out = []
    got = by.get("pose")
    keys = {k: str(v) for k, v in (got.keys if got else {}).items()}
    if keys != pose:
        out.append(f"pose: {keys} instead of {pose}")
    if got is not None and got.ambiguous != pose_ambiguous:
        out.append(f"pose: ambiguous {got.ambiguous} instead of {pose_ambiguous}")
    lid = by.get("lidar")
    declared = [c.name for c in lid.candidates if c.usable] if lid else []
    if declared != list(lidars):
        out.append(f"lidar: {declared} instead of {list(lidars)}")
    for topic, frame in camera_frames.items():
        cam = by.get(f"camera {topic}")
        if cam is None or cam.chosen != frame:
            out.append(f"camera {topic}: {cam.chosen if cam else '(none)'} instead of {frame}")
    return out
