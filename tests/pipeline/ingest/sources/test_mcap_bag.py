"""Loose MCAP files (`mcap convert` of a ROS1 bag: profile ros1; or profile ros2) read like the
bags they came from: same messages in the same order, same index, damage and unsupported input
named."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from rosbags.convert.converter import convert
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.typesys import Stores, get_typestore

from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.bags import BagFile, find_bags
from pipeline.ingest.sources.sweep_reader import load_sweep
from pipeline.synth.mcap_write import bag_to_mcap, bags_to_mcap
from schemas.config import IngestConfig
from schemas.errors import DataError, MissingInputError
from schemas.recording_index import SWEEPS, read_index_table, table_path
from tests.pipeline.ingest.bagkit import Mission, write_mission

CFG = IngestConfig(cameras=["front"], out_height=28, out_width=42)
SAME_BUT_FILE = ("images", "sweeps", "accounting")
"""Index tables whose only difference is the `file` column (the source's own name)."""


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(mission of ROS1 bags, the same mission as one .mcap per bag, profile ros1)."""
    root = tmp_path_factory.mktemp("mcap")
    bags = write_mission(root / "bag", Mission(seconds=0.5))
    mcaps = root / "mcap" / "m0"
    bags_to_mcap(sorted(bags.glob("*.bag")), mcaps)
    return bags, mcaps


def _all(bag: BagFile) -> list[tuple[str, str, int, int, bytes, str]]:
    """Every message of a bag: topic, type, log time, ordinal, bytes, digest."""
    return [(m.topic, m.msgtype, m.bag_time_ns, m.ordinal, m.raw, m.digest)
            for m in bag.messages(bag.topics())]  # fmt: skip


def test_mcap_written_as_mcap_convert_writes_a_bag(pair: tuple[Path, Path]) -> None:
    with (pair[1] / "m0_hdr_front.mcap").open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros1"
        summary = reader.get_summary()
    assert summary is not None
    assert {s.encoding for s in summary.schemas.values()} == {"ros1msg"}
    assert {s.name for s in summary.schemas.values()} == {"sensor_msgs/CompressedImage",
                                                          "sensor_msgs/CameraInfo"}
    assert all(c.message_encoding == "ros1" and c.metadata["md5sum"]
               for c in summary.channels.values())  # fmt: skip


def test_every_message_the_same_as_from_the_bag(pair: tuple[Path, Path]) -> None:
    for path in sorted(pair[0].glob("*.bag")):
        bag, mcap = BagFile(path, pair[0]), BagFile(pair[1] / f"{path.stem}.mcap", pair[1])
        try:
            assert mcap.kind == "mcap-ros1" and not mcap.ros2 and bag.kind == "rosbag1"
            assert mcap.topics() == bag.topics()
            got, want = _all(mcap), _all(bag)
            assert got == want and got
            for msg in mcap.messages(mcap.topics(), start=want[len(want) // 2][2]):
                assert repr(mcap.deserialize(msg)) == repr(bag.deserialize(
                    next(m for m in bag.messages([msg.topic], start=msg.bag_time_ns))))
            assert mcap.damage is None
        finally:
            bag.close()
            mcap.close()


def test_ingest_gives_the_same_index(pair: tuple[Path, Path], tmp_path: Path) -> None:
    a = ingest_recording(pair[0], tmp_path / "a", CFG)
    b = ingest_recording(pair[1], tmp_path / "b", CFG)
    assert (a.images, a.sweeps, a.odometry) == (b.images, b.sweeps, b.odometry) == (
        {"front": 5}, 5, 16)  # fmt: skip
    assert a.rejects == b.rejects == {} and b.input_format == "mcap-ros1, detected"
    for name in ("calibration", "odometry", "rejects", "damage"):
        assert (table_path(a.index_dir, name).read_bytes()
                == table_path(b.index_dir, name).read_bytes()), name  # fmt: skip
    for name in SAME_BUT_FILE:
        ta, tb = (pq.read_table(table_path(i, name)) for i in (a.index_dir, b.index_dir))
        assert ta.drop_columns("file").equals(tb.drop_columns("file")), name
        assert {f.replace(".bag", ".mcap") for f in ta.column("file").to_pylist()} == set(
            tb.column("file").to_pylist())  # fmt: skip
    row_a, row_b = (read_index_table(table_path(i, "sweeps"), SWEEPS).to_pylist()[2]
                    for i in (a.index_dir, b.index_dir))  # fmt: skip
    sa, sb = load_sweep(pair[0], row_a), load_sweep(pair[1], row_b)
    np.testing.assert_array_equal(sa.xyz, sb.xyz)
    np.testing.assert_array_equal(sa.t_ns, sb.t_ns)


def test_latched_channels_from_channel_metadata(tmp_path: Path) -> None:
    ts = get_typestore(Stores.ROS1_NOETIC)
    msg = ts.types["std_msgs/msg/String"](data="x")
    with Ros1Writer(tmp_path / "l.bag") as w:
        latched = w.add_connection("/static", "std_msgs/msg/String", typestore=ts, latching=1)
        plain = w.add_connection("/plain", "std_msgs/msg/String", typestore=ts)
        for conn in (latched, plain):
            w.write(conn, 5, ts.serialize_ros1(msg, "std_msgs/msg/String"))
    path = bag_to_mcap(tmp_path / "l.bag", tmp_path / "l.mcap")
    bag = BagFile(path, tmp_path)
    try:
        assert bag.mcap is not None and bag.mcap.latched == {"/static"}
    finally:
        bag.close()


def test_ros2_profile_and_a_rosbag2_folder_holding_a_ros1_mcap(pair: tuple[Path, Path],
                                                               tmp_path: Path) -> None:
    """A loose ROS 2 MCAP reads as its rosbag2 folder does; a rosbag2 folder whose one MCAP is
    in profile ros1 (rosbags refuses it: "Profile is not ros2") reads as that MCAP."""
    src = pair[0] / "m0_tf_minimal.bag"
    convert([src], tmp_path / "r2", "mcap", 9, None, "file", None,
            get_typestore(Stores.ROS2_HUMBLE), [], [], [], [])  # fmt: skip
    [storage] = (tmp_path / "r2").glob("*.mcap")
    loose = tmp_path / "loose" / "tf.mcap"
    loose.parent.mkdir()
    shutil.copy(storage, loose)
    wrapped = tmp_path / "wrapped"
    wrapped.mkdir()
    shutil.copy(tmp_path / "r2" / "metadata.yaml", wrapped / "metadata.yaml")
    shutil.copy(pair[1] / "m0_tf_minimal.mcap", wrapped / storage.name)
    bags = [BagFile(tmp_path / "r2", tmp_path), BagFile(loose, loose.parent),
            BagFile(wrapped, tmp_path), BagFile(src, pair[0])]
    try:
        assert [b.kind for b in bags] == ["rosbag2", "mcap-ros2", "mcap-ros1", "rosbag1"]
        r2, mcap2, wrapped1, ros1 = (_all(b) for b in bags)
        assert mcap2 == r2 and wrapped1 == ros1
        first = next(bags[1].messages(bags[1].topics()))
        assert bags[1].deserialize(first).transforms
    finally:
        for b in bags:
            b.close()


def test_a_rosbag2_folder_of_several_ros1_mcap_files_is_unsupported(pair: tuple[Path, Path],
                                                                    tmp_path: Path) -> None:
    folder = tmp_path / "r2"
    folder.mkdir()
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 5}\n")
    for name in ("m0_tf_minimal", "m0_anymal_state"):
        shutil.copy(pair[1] / f"{name}.mcap", folder / f"{name}.mcap")
    with pytest.raises(DataError) as err:
        BagFile(folder, tmp_path)
    assert str(err.value).startswith(f"{folder}: unsupported rosbag2 folder: MCAP storage in "
                                     "profile 'ros1' (rosbag2 reads 'ros2'")


def _mcap(path: Path, profile: str, message_encoding: str, schema_encoding: str) -> Path:
    """A one-message MCAP file of the given profile and encodings."""
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile=profile)
        sid = w.register_schema("std_msgs/String", schema_encoding, b"string data")
        cid = w.register_channel("/chatter", message_encoding, sid)
        w.add_message(cid, log_time=1, data=b"\x01\x00\x00\x00x", publish_time=1)
        w.finish()
    return path


@pytest.mark.parametrize(("profile", "encodings", "said"), [
    ("foxglove", ("json", "jsonschema"), "unsupported MCAP profile 'foxglove'"),
    ("ros1", ("json", "jsonschema"), "unsupported MCAP channel /chatter (message encoding 'json'"),
    ("ros2", ("ros1", "ros1msg"), "profile ros2 needs 'cdr' with ros2msg or ros2idl"),
])
def test_unsupported_mcap_is_named_as_such(tmp_path: Path, profile: str,
                                           encodings: tuple[str, str], said: str) -> None:
    path = _mcap(tmp_path / "x.mcap", profile, *encodings)
    with pytest.raises(DataError, match="unsupported") as err:
        BagFile(path, tmp_path)
    assert said in str(err.value) and str(path) in str(err.value)
    assert "unreadable" not in str(err.value) and "\n" not in str(err.value)


def test_a_folder_without_bags_names_what_it_skipped(tmp_path: Path) -> None:
    (tmp_path / "rec_0.db3").write_bytes(b"SQLite format 3\x00")
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "sub").mkdir()
    _mcap(tmp_path / "rec.bin", "ros1", "ros1", "ros1msg")
    with pytest.raises(MissingInputError) as err:
        find_bags(tmp_path)
    text = str(err.value)
    assert "no ROS1 .bag files, .mcap files or ROS2 bag folders (skipped: " in text
    for part in ("notes.txt (not a .bag, .mcap or ROS2 bag folder)",
                 "rec.bin (MCAP content without the .mcap suffix)",
                 "rec_0.db3 (ROS2 sqlite3 storage without the metadata.yaml of its bag folder)",
                 "sub (a folder without metadata.yaml: not a ROS2 bag)"):
        assert part in text


def test_a_damaged_chunk_is_a_region_and_the_rest_is_read(pair: tuple[Path, Path],
                                                          tmp_path: Path) -> None:
    path = bag_to_mcap(pair[0] / "m0_hdr_front.bag", tmp_path / "m0_hdr_front.mcap",
                       chunk_size=2048)  # fmt: skip
    clean = BagFile(path, tmp_path)
    want = _all(clean)
    clean.close()
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) > 2
    hit = chunks[1]
    data = bytearray(path.read_bytes())
    middle = hit.chunk_start_offset + hit.chunk_length // 2
    data[middle:middle + 16] = bytes(16)
    path.write_bytes(bytes(data))
    bag = BagFile(path, tmp_path)
    try:
        got = _all(bag)
        [region] = bag.regions
        assert (region.byte_start, region.byte_end) == (
            hit.chunk_start_offset, hit.chunk_start_offset + hit.chunk_length)  # fmt: skip
        kept = [(m[0], m[2], m[4]) for m in got]
        lost = [m for m in want if (m[0], m[2], m[4]) not in kept]
        assert region.messages == len(lost) == len(want) - len(got) > 0
        assert all(region.first_ns <= m[2] <= region.last_ns for m in lost)
        assert [(m[0], m[2], m[4]) for m in want if m not in lost] == kept  # order kept
        assert bag.damage is not None and f"chunk at byte {hit.chunk_start_offset}" in bag.damage
    finally:
        bag.close()


SOURCE_NAMED = ("manifest.json", "cache_done/", "stats/latent_parts/")
"""Outputs that carry the source's identity (file names, the cache key hashed over them)."""


@pytest.mark.slow
def test_inspect_and_run_on_mcap_copies_of_a_synthetic_recording(tmp_path: Path) -> None:
    """`m3gd inspect` and a full run on one .mcap per bag give what they give on the bags: every
    cache array, packet and statistic byte-identical; only names of the source differ."""
    from typer.testing import CliRunner

    from cli.app import app
    from dags.graph import STAGES
    from pipeline.run.service import run_stages
    from pipeline.synth.api import synthesize
    from tests.dags.conftest import synth_config, tiny_config

    bags = Path(str(synthesize(tmp_path / "bag", synth_config(), "corridor",
                               mission="t_m").mission_dir))  # fmt: skip
    mcaps = tmp_path / "mcap" / "t_m"
    bags_to_mcap(sorted(bags.glob("*.bag")), mcaps)
    for rec in (bags, mcaps):
        summaries = run_stages(tiny_config(tmp_path / f"out_{rec.parent.name}", [rec]),
                               STAGES).summaries  # fmt: skip
        assert not any(s.failed for s in summaries), [s.failed for s in summaries]
    shown = []
    for rec in (bags, mcaps):
        out = CliRunner().invoke(app, ["inspect", "--json", str(rec)])
        assert out.exit_code == 0, out.output
        shown.append(json.loads(out.stdout))
    a, b = shown
    assert (a["format"], b["format"]) == ("rosbag1", "mcap-ros1")
    for key in a.keys() - {"path", "format", "files", "seconds", "topics"}:
        assert a[key] == b[key], key
    assert [{**t, "files": []} for t in a["topics"]] == [{**t, "files": []} for t in b["topics"]]
    root_a, root_b = tmp_path / "out_bag", tmp_path / "out_mcap"
    files = sorted(str(p.relative_to(root_a)) for p in root_a.rglob("*") if p.is_file())
    assert files == sorted(str(p.relative_to(root_b)) for p in root_b.rglob("*") if p.is_file())
    same = 0
    for name in files:
        fa, fb = root_a / name, root_b / name
        if name.endswith(".crc32c") or name.startswith(SOURCE_NAMED):
            continue
        if name.startswith("index/") and name.endswith(".parquet"):
            ta, tb = pq.read_table(fa), pq.read_table(fb)
            named = [c for c in ("file", "seconds") if c in ta.column_names]  # and wall time
            assert ta.drop_columns(named).equals(tb.drop_columns(named)), name
            continue
        assert fa.read_bytes() == fb.read_bytes(), name
        same += 1
    assert same > 100 and any("cache" in f and ".zarr" in f for f in files)


def test_a_rosbag2_folder_of_several_ros1_mcap_files_is_read_file_by_file(
        pair: tuple[Path, Path], tmp_path: Path) -> None:
    """As a mission folder and as a folder inside one, its ros1 MCAP files are the bags: the
    same messages as the loose files, not "Profile is not ros2"."""
    folder = tmp_path / "r2"
    folder.mkdir()
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 5}\n")
    names = ("m0_tf_minimal", "m0_anymal_state")
    for name in names:
        shutil.copy(pair[1] / f"{name}.mcap", folder / f"{name}.mcap")
    for mission in (folder, tmp_path):
        paths = find_bags(mission)
        assert sorted(p.name for p in paths) == sorted(f"{n}.mcap" for n in names)
        bags = [BagFile(p, mission) for p in paths]
        loose = [BagFile(pair[1] / p.name, pair[1]) for p in paths]
        try:
            assert {b.kind for b in bags} == {"mcap-ros1"}
            assert [_all(b) for b in bags] == [_all(b) for b in loose]
        finally:
            for b in bags + loose:
                b.close()
