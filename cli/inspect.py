"""`m3gd inspect`: what a recording holds (topics, TF tree, LiDAR layout and point-time
evidence, cameras), from its indexes and a few messages; optionally a configuration for it.
The logic lives in `pipeline.inspect`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from cli.common import fail, stdout, styled, write_json

HEADER = "# written by m3gd inspect"
"""First line of a configuration inspect writes: the only kind of file it overwrites."""


def _ours(path: Path) -> bool:
    """Whether an existing `path` is a configuration written by inspect, or an empty file
    (nothing to lose: what a write cut before the atomic writes left)."""
    if not path.is_file():
        return False
    if path.stat().st_size == 0:
        return True
    with path.open("rb") as f:
        return f.read(len(HEADER)) == HEADER.encode()


def inspect(
    recording: Annotated[Path, typer.Argument(
        help="A ROS1 .bag file, an .mcap file (profile ros1 or ros2), a ROS2 bag folder (db3 or "
             "MCAP), a mission folder of bags or a mission in the Hugging Face layout.",
        show_default=False)],
    as_json: Annotated[bool, typer.Option("--json", help="Print the inspection as JSON.")
                       ] = False,
    write_config: Annotated[Path | None, typer.Option(
        "--write-config", help="Write a configuration for this recording that `m3gd run` "
        "accepts (YAML; only the keys inspect decides, the rest default). Written whole or "
        "not at all (a temporary renamed over it); a symbolic link is written through.")
        ] = None,
    no_verify: Annotated[bool, typer.Option(
        "--no-verify", help="With --write-config: do not prove the decisions by their geometry "
        "(by default every decision with candidates is judged by the run's geometry check on "
        "a few views per camera and the one whose LiDAR edges meet the image edges is kept).")
        ] = False,
) -> None:
    """What a recording holds, read from its indexes and a few messages: topics, types,
    counts, rates and gaps; the TF tree; per PointCloud2 topic its fields and point-time
    evidence; per camera its encoding, model and resolution."""
    from pipeline.inspect.config_out import build_config, decision_lines
    from pipeline.inspect.config_out import write_config as write
    from pipeline.inspect.prove import prove_or_say
    from pipeline.inspect.recording import inspect_recording
    from schemas.errors import DataError, MissingInputError

    if not recording.exists():
        fail(f"{recording}: no such file or folder", 2)
    if write_config is not None and write_config.exists() and not _ours(write_config):
        fail(f"{write_config}: an existing file that m3gd inspect did not write; choose another "
             "path for the configuration or remove it", 2)
    try:
        ins = inspect_recording(recording)
    except MissingInputError as err:
        fail(str(err), 2)
    except (DataError, OSError) as err:
        fail(f"{recording}: cannot be read: {err}")
    warnings: list[str] = []
    report = None
    if write_config is not None:
        if not no_verify:
            report, ins = prove_or_say(ins, recording)
        cfg, warnings = build_config(ins, recording)
        try:
            write(cfg, write_config, warnings, decision_lines(ins, report))
        except OSError as err:
            fail(f"{write_config}: cannot write the configuration: {err}")
    if as_json:
        data = ins.as_dict()
        _time_beside(data, report)
        if write_config is not None:
            data["config"] = {"path": str(write_config), "warnings": warnings}
            data["proof"] = report.as_dict() if report is not None else None
        write_json(data)
    else:
        _print(ins, report)
        if write_config is not None:
            stdout.print(f"configuration written: {write_config} (m3gd -c {write_config} run)",
                         highlight=False)
            for w in warnings:
                stdout.print(styled(("note", "yellow"), f" {w}"))
            _print_proof(report)
    if report is not None and report.disagrees:
        fail(f"{write_config}: geometry disagrees for every candidate of "
             f"{', '.join(p.what for p in report.disagrees)}: no choice puts the LiDAR's edges "
             "on the images' (the configuration is written; check the frames and the pose "
             "source, or skip the proof with --no-verify)")


def _print_proof(report: Any) -> None:
    """The proof: one line per decision, its time."""
    if report is None:
        stdout.print("geometry: not proven (--no-verify)", highlight=False)
        return
    for p in report.proofs:
        loud = p.status in ("switched", "disagrees")
        stdout.print(styled(("geometry", "red" if loud else "green"),
                            f" {p.what}: {p.summary()}"))
    for why in report.problems:
        stdout.print(styled(("geometry", "yellow"), f" not read: {why}"))
    stdout.print(f"geometry proof: {report.seconds:.2f} s", highlight=False)


def _f(value: float | None, fmt: str = ".3g") -> str:
    """A number or '-'."""
    return "-" if value is None else format(value, fmt)


def _print(ins: Any, report: Any = None) -> None:
    """The inspection as tables and lines."""
    from pipeline.inspect.tf import tree_lines

    stdout.print(f"{ins.path}: {ins.format}, {len(ins.files)} file(s), {ins.bytes / 1e6:.1f} MB,"
                 f" inspected in {ins.seconds:.2f} s", highlight=False)
    table = Table(title="topics (from the indexes: log times)")
    for col in ("topic", "type", "messages", "Hz", "period ms", "gaps", "longest gap s"):
        table.add_column(col, justify="left" if col in ("topic", "type") else "right")
    for t in ins.topics:
        longest = t.gaps[0].seconds if t.gaps else None
        table.add_row(t.topic, t.msgtype, str(t.count), _f(t.rate_hz, ".4g"),
                      _f(None if t.period_s is None else t.period_s * 1e3, ".4g"),
                      str(t.n_gaps), _f(longest))  # fmt: skip
    stdout.print(table)
    stdout.print("TF tree (parent -> child as written):", highlight=False)
    for line in tree_lines(ins.tf) or ["(no transforms)"]:
        stdout.print(f"  {line}", highlight=False)
    stdout.print(f"  roots: {', '.join(ins.tf.roots) or '-'}; dynamic messages sampled: "
                 f"{ins.tf.sampled or '-'}", highlight=False)
    for child, parents in ins.tf.multiple_parents.items():
        stdout.print(styled("  ", (f"{child} has {len(parents)} parents: "
                                   f"{', '.join(parents)}", "red")))
    for c in ins.clouds:
        _print_cloud(c, _time_proof(report, c.topic))
    for cam in ins.cameras:
        _print_camera(cam)
    for topic, frame, child in ins.odometry:
        stdout.print(f"odometry {topic}: {frame} -> {child or '(no child frame: the base frame)'}",
                     highlight=False)
    for d in ins.decisions:
        stdout.print(styled(("ambiguous", "red") if d.ambiguous else "decided", f" {d.line()}"))
    for note in ins.notes:
        stdout.print(styled(("note", "yellow"), f" {note}"))


def _time_proof(report: Any, topic: str) -> Any:
    """The proof of `topic`'s point-time convention, or None."""
    return None if report is None else report.of(f"point_time {topic}")


def _time_beside(data: dict[str, Any], report: Any) -> None:
    """Each LiDAR's point-time proof beside its convention in the JSON (`geometry`: status,
    kept, the one-line summary)."""
    for cloud in data.get("clouds", []):
        proof = _time_proof(report, str(cloud.get("topic")))
        if proof is not None and isinstance(cloud.get("convention"), dict):
            cloud["convention"]["geometry"] = {"status": proof.status, "kept": proof.kept,
                                               "line": proof.summary()}  # fmt: skip


def _print_cloud(c: Any, proof: Any = None) -> None:
    """One PointCloud2 topic: layout and time evidence."""
    stdout.print(f"LiDAR {c.topic} (frame {c.frame_id}): point_step {c.point_step}, "
                 f"{c.width}x{c.height}, is_dense {c.is_dense}, "
                 f"{'big' if c.is_bigendian else 'little'} endian", highlight=False)
    stdout.print("  fields: " + ", ".join(f"{f.name} {f.dtype}@{f.offset}"
                                          + (f"x{f.count}" if f.count > 1 else "")
                                          for f in c.fields), highlight=False)  # fmt: skip
    if c.error:
        stdout.print(styled("  ", (f"cannot decode: {c.error}", "red")))
    stdout.print(f"  time field: {c.time_field or 'none'} {c.time_dtype or ''}; sweep period "
                 f"{_f(None if c.sweep_period_s is None else c.sweep_period_s * 1e3, '.4g')} ms "
                 f"(header stamps of {len(c.sweeps)} sweeps)", highlight=False)
    for s in c.sweeps[:2]:
        if s.raw_min is not None:
            stdout.print(f"  sweep at header {s.header_ns} ns: values {s.raw_min!r} .. "
                         f"{s.raw_max!r} ({s.points} points, {s.n_nonfinite} non-finite)",
                         highlight=False)
    for u in c.units:
        stdout.print(f"  read as {u.unit:>2}: span {u.span_s * 1e3:.6g} ms; first point "
                     f"{u.offset_if_absolute_s * 1e3:.6g} ms from the header if absolute, "
                     f"{u.offset_if_relative_s * 1e3:.6g} ms if relative", highlight=False)
    conv = c.convention
    stdout.print(f"  convention ({conv.decided_by}): unit {conv.unit or '-'}, reference "
                 f"{conv.reference or '-'}; {conv.note}", highlight=False)
    if proof is not None:
        loud = proof.status in ("switched", "disagrees")
        stdout.print(styled(("  geometry", "red" if loud else "green"), f" {proof.summary()}"))


def _print_camera(cam: Any) -> None:
    """One camera: encoding, size, calibration and its changes."""
    sizes = ", ".join(f"{w}x{h}" for w, h in cam.image_sizes) or "-"
    stdout.print(f"camera {cam.image_topic} ({cam.image_type}, frame {cam.frame_id or '?'}): "
                 f"{cam.encoding}, {sizes}", highlight=False)
    if cam.error:
        stdout.print(styled("  ", (str(cam.error), "red")))
    if not cam.calibrations:
        stdout.print(f"  calibration: none ({cam.info_topic or 'no CameraInfo topic'})",
                     highlight=False)
        return
    c = cam.calibrations[0]
    stdout.print(styled(f"  calibration {cam.info_topic}: {c.distortion_model} "
                        f"({c.n_coefficients} coefficients), {c.width}x{c.height}, fx "
                        f"{c.fx:.6g} fy {c.fy:.6g} cx {c.cx:.6g} cy {c.cy:.6g}; "
                        f"{len(cam.calibrations)} sampled, ",
                        ("it changes", "red") if cam.calibration_changes else "no change"))
    if cam.calibration_changes:
        for c in cam.calibrations:
            stdout.print(f"    at {c.stamp_ns} ns: {c.distortion_model}, {c.width}x{c.height}, "
                         f"fx {c.fx:.6g}", highlight=False)
