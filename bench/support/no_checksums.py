"""A copy of cache arrays without their chunk checksums: the layout of cache format 2 (chunks
back to back, no CRC32C), so `m3gd bench cache` can state what the checksums cost a read
against the same reader on the same values in the same run."""

from __future__ import annotations

import json
from pathlib import Path

from store.raw_shard import CRC_BYTES, MISSING, crc_bytes
from store.shard_layout import ArrayMeta, index_pairs


def strip_checksums(src: Path, dst: Path) -> None:
    """Write the sharded array at `src` to `dst` (a new directory) with the crc32c codec
    dropped from its inner codecs and every stored chunk without its 4 CRC bytes, back to
    back; the shard index keeps its own CRC32C (format 2 had it too)."""
    meta_json = json.loads((src / "zarr.json").read_text())
    meta = ArrayMeta.parse(meta_json)
    if meta is None or not meta.sharded or not meta.crc:
        raise ValueError(f"{src}: not a sharded array with chunk checksums")
    inner = meta_json["codecs"][0]["configuration"]["codecs"]
    meta_json["codecs"][0]["configuration"]["codecs"] = inner[:-1]
    dst.mkdir(parents=True)
    (dst / "zarr.json").write_text(json.dumps(meta_json))
    n = meta.file_views * meta.chunks_per_view
    for shard in (p for p in src.rglob("*") if p.is_file() and p.name != "zarr.json"):
        raw = shard.read_bytes()
        index = index_pairs(raw, n).copy()
        body = bytearray()
        for entry in index:
            if entry[0] != MISSING:
                start, stored = int(entry[0]), int(entry[1])
                entry[:] = (len(body), stored - CRC_BYTES)
                body += raw[start:start + stored - CRC_BYTES]
        out = dst / shard.relative_to(src)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(bytes(body) + index.tobytes() + crc_bytes(index.tobytes()))


def strip_group(src: Path, dst: Path, names: list[str]) -> None:
    """`strip_checksums` of arrays `names` of the cache group at `src` into group `dst`
    (its zarr.json copied)."""
    dst.mkdir(parents=True)
    (dst / "zarr.json").write_bytes((src / "zarr.json").read_bytes())
    for name in names:
        strip_checksums(src / name, dst / name)
