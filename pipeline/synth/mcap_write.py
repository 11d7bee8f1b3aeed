"""ROS1 bags to loose MCAP files in profile `ros1`, as `mcap convert x.bag x.mcap` writes them.

One `.mcap` per bag: a schema per message type (encoding `ros1msg`, the connection's full
message definition, the ROS1 type name), a channel per connection in connection order (message
encoding `ros1`, metadata `md5sum`, and `callerid` / `latching` where the connection header has
them), the raw ROS1 bytes of every message at its bag time, in zstd chunks with CRCs and message
indexes. Used by the tests and by anyone who wants MCAP copies of a synthetic recording.
"""

from __future__ import annotations

from pathlib import Path

from mcap.writer import CompressionType, Writer
from rosbags.interfaces import ConnectionExtRosbag1
from rosbags.rosbag1 import Reader

PROFILE = "ros1"
LIBRARY = "m3gd synth"


def ros1_name(msgtype: str) -> str:
    """`pkg/msg/Type` (rosbags' name of a ROS1 type) as ROS1 writes it: `pkg/Type`."""
    return msgtype.replace("/msg/", "/", 1)


def bag_to_mcap(bag: Path, dst: Path, chunk_size: int = 1 << 20) -> Path:
    """Write `dst` (a new `.mcap` file) holding every message of ROS1 bag `bag`; returns it."""
    with Reader(bag) as reader, dst.open("xb") as out:
        writer = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        writer.start(profile=PROFILE, library=LIBRARY)
        schemas: dict[tuple[str, str], int] = {}
        channels: dict[int, int] = {}
        for conn in reader.connections:
            key = (conn.msgtype, conn.digest)
            if key not in schemas:
                schemas[key] = writer.register_schema(
                    ros1_name(conn.msgtype), "ros1msg", conn.msgdef.data.encode())
            meta = {"md5sum": conn.digest}
            ext = conn.ext
            if isinstance(ext, ConnectionExtRosbag1) and ext.callerid:
                meta["callerid"] = ext.callerid
            if isinstance(ext, ConnectionExtRosbag1) and ext.latching is not None:
                meta["latching"] = str(ext.latching)
            channels[conn.id] = writer.register_channel(conn.topic, "ros1", schemas[key], meta)
        for seq, (conn, stamp, raw) in enumerate(reader.messages()):
            writer.add_message(channels[conn.id], log_time=stamp, data=bytes(raw),
                               publish_time=stamp, sequence=seq)  # fmt: skip
        writer.finish()  # type: ignore[no-untyped-call]
    return dst


def bags_to_mcap(bags: list[Path], out_dir: Path) -> list[Path]:
    """MCAP copies (`<out_dir>/<stem>.mcap`, profile ros1) of finished ROS1 bags."""
    out_dir.mkdir(parents=True, exist_ok=True)
    return [bag_to_mcap(bag, out_dir / f"{bag.stem}.mcap") for bag in bags]
