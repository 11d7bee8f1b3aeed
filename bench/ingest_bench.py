"""Ingest benchmark: time against the read+decode floor, peak RSS against recording length.

All numbers are measured in the same run:
- `ingest_over_floor`: wall time of `ingest_recording` (index + every image decoded, rectified
  and resized, every sweep decoded for its counts) over the floor, which is iterating the same
  bags with rosbags and `cv2.imdecode` of every image message at full size (goal <= 1.3), on a
  GrandTour-sized recording (1920x1280 images); process CPU time, best of 3 alternating runs
  after a warm-up of each (wall-time ratio reported beside it). The same
  ratio on small (480x320) synthetic images is reported as `ingest_over_floor_small_images`:
  there the remap costs as much as the decode and the ratio is higher.
- `ingest_over_floor_judged`: the GrandTour-sized ratio with every message judged by the checks
  (`ingest.checks.trust_checksums` off, as on bags whose chunks carry no checksum; the bags and
  the floor are the same), goal <= 1.3; `ingest_over_floor_small_images_judged` likewise.
- `rss_ratio_2x_length`: peak RSS of ingesting a recording of length 2L over length L, each in
  a fresh subprocess (goal: flat within 10%); the increments over the post-import RSS are
  reported too, since the import baseline dominates small recordings.
- `hf_ingest_over_floor`: the same GrandTour-sized recording in the Hugging Face layout
  (written from its bags): `ingest_recording` over reading every JPEG file and imdecoding it at
  full size plus reading every scan's valid points and the odometry arrays (same protocol).
  `hf_over_bag_ingest`: HF ingest CPU time over bag ingest CPU time of that recording.
  `hf_rss_ratio_2x_length`: as `rss_ratio_2x_length`, on HF copies of the L and 2L recordings.
- `decode_choices`: time and PSNR of each JPEG reduction x map precision, on the recording's
  own images and on a GrandTour-sized (1920x1280) fisheye image.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bench.decode_choice import measure_choices
from bench.measure import fastest
from pipeline.ingest.calib.camera import RawCamera
from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.bags import BagFile, find_bags
from pipeline.ingest.sources.static import read_static
from schemas.config import IngestConfig, SynthConfig

GRANDTOUR_K = np.array([[900.0, 0.0, 959.5], [0.0, 900.0, 639.5], [0.0, 0.0, 1.0]])
GRANDTOUR_D = np.array([-0.03, 0.004, -0.002, 0.0005])
"""A GrandTour-like equidistant HDR camera (1920x1280); illustrative values, not a calibration."""


def make_recording(
    root: Path, seconds: float, seed: int = 0, scene: str = "corridor", **synth: Any
) -> Path:
    """A synthetic recording of `seconds` length under `root`; returns its mission folder."""
    from pipeline.synth.api import synthesize

    mission = f"bench_{scene}_{int(seconds * 1000)}ms_{synth.get('image_width', 'dflt')}"
    cfg = SynthConfig(seconds=seconds, seed=seed, scenes=[scene], **synth)
    synthesize(root, cfg, scene, mission)
    return root / mission


def floor_seconds(mission: Path, cfg: IngestConfig) -> tuple[float, int]:
    """Time to iterate the configured topics of every bag and imdecode every image; and count."""
    t = cfg.topics
    images = {t.image_topic(c) for c in cfg.cameras}
    topics = [*images, t.lidar, t.odometry, t.tf_static, *(t.info_topic(c)
                                                            for c in cfg.cameras)]  # fmt: skip
    t0 = time.perf_counter()
    n = 0
    for path in find_bags(mission):
        bag = BagFile(path, mission)
        for msg in bag.messages(topics):
            if msg.topic in images:
                data = np.asarray(bag.deserialize(msg).data, dtype=np.uint8)
                cv2.imdecode(data, cv2.IMREAD_COLOR)
                n += 1
        bag.close()
    return time.perf_counter() - t0, n


def _warm(mission: Path) -> None:
    """Read every file once so both timings see a warm page cache."""
    for p in mission.rglob("*"):
        if p.is_file():
            p.read_bytes()


_RSS_CHILD = """
import json, sys
from pathlib import Path
from bench.measure import PeakRSS
from pipeline.ingest.recording import ingest_recording
from schemas.config import IngestConfig
cfg = IngestConfig.model_validate_json(sys.argv[3])
with PeakRSS(period_s=0.002) as rss:
    ingest_recording(Path(sys.argv[1]), Path(sys.argv[2]), cfg)
print(json.dumps({"base_mb": rss.base / 2**20, "peak_mb": (rss.base + rss.peak) / 2**20}))
"""


def peak_rss_mb(mission: Path, out_dir: Path, cfg: IngestConfig) -> dict[str, float]:
    """Peak RSS (MB, sampled every 2 ms) while ingesting `mission` in a fresh interpreter, and
    the RSS just before ingest (after imports)."""
    args = [sys.executable, "-c", _RSS_CHILD, str(mission), str(out_dir), cfg.model_dump_json()]
    proc = subprocess.run(args, capture_output=True, text=True, check=True)
    out: dict[str, float] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


def _timed(fn: Any) -> tuple[float, float]:
    """(wall s, process CPU s) of one call."""
    wall, cpu, _ = fastest(fn)
    return wall, cpu


def hf_floor_seconds(mission: Path, cfg: IngestConfig) -> tuple[float, int]:
    """Time to read every JPEG file of the cameras and imdecode it at full size, and to read
    every scan's valid points and the odometry arrays chunk by chunk (the HF floor); count."""
    from pipeline.ingest.sources.hf.points import ScanReader
    from pipeline.ingest.sources.hf.store import HfStore

    t0 = time.perf_counter()
    store = HfStore.open(mission)
    n = 0
    for cam in cfg.cameras:
        for path in sorted((mission / "images" / cfg.hf.group(cam)).iterdir()):
            cv2.imdecode(np.frombuffer(path.read_bytes(), np.uint8), cv2.IMREAD_COLOR)
            n += 1
    for _ in ScanReader(store, cfg.hf.lidar_group).rows():
        pass
    for name in ("pose_pos", "pose_orien", "timestamp"):
        store.array(cfg.hf.odometry_group, name)[:]
    return time.perf_counter() - t0, n


def timed_ratio(
    mission: Path, out_dir: Path, cfg: IngestConfig, repeats: int = 3, floor: Any = floor_seconds
) -> dict[str, float]:
    """Ingest vs floor, best of `repeats` alternating runs after one warm-up of each.

    Both wall and process-CPU times are kept; `ratio` is on CPU time, which other processes on
    a shared machine disturb less than wall time (`ratio_wall` beside it).
    """
    _warm(mission)
    floor(mission, cfg)
    ingest_recording(mission, out_dir, cfg)
    floors, ingests = [], []
    for _ in range(repeats):
        floors.append(_timed(lambda: floor(mission, cfg)))
        ingests.append(_timed(lambda: ingest_recording(mission, out_dir, cfg)))
    fw, fc = min(f[0] for f in floors), min(f[1] for f in floors)
    iw, ic = min(i[0] for i in ingests), min(i[1] for i in ingests)
    return {"ingest_cpu_s": ic, "floor_cpu_s": fc, "ratio": ic / fc,
            "ingest_wall_s": iw, "floor_wall_s": fw, "ratio_wall": iw / fw}  # fmt: skip


def _hf_copy(mission: Path, root: Path, cameras: Any = ("front",)) -> Path:
    """The same recording in the Hugging Face layout (written from its bags)."""
    from pipeline.synth.hf_convert import bags_to_hf
    from schemas.config import TopicsConfig

    dst = root / mission.name
    bags_to_hf(find_bags(mission), dst, TopicsConfig(), list(cameras))
    return dst


def grandtour_choices(n: int = 3) -> list[dict[str, object]]:
    """Decode-choice table on GrandTour-sized JPEGs of a smooth textured scene."""
    cam = RawCamera("front", "hdr_front", 1920, 1280, "equidistant", GRANDTOUR_K, GRANDTOUR_D)
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:1280, 0:1920].astype(np.float32)
    jpegs = []
    for i in range(n):
        f = rng.uniform(10, 40, 3)
        smooth = np.stack([128 + 60 * np.sin(xx / f[0] + i), 128 + 60 * np.cos(yy / f[1]),
                           128 + 50 * np.sin((xx + yy) / f[2])], -1)  # fmt: skip
        blocks = cv2.resize(rng.uniform(-60, 60, (320, 480, 3)).astype(np.float32), (1920, 1280),
                            interpolation=cv2.INTER_NEAREST)  # 4 px detail, as in real scenes
        img = np.clip(smooth + blocks, 0, 255).astype(np.uint8)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        jpegs.append(buf.tobytes())
    return measure_choices(jpegs, cam, (224, 336))


def _recording_choices(mission: Path, cfg: IngestConfig, n: int = 10) -> list[dict[str, object]]:
    """Decode-choice table on the first `n` images of the recording's first camera."""
    cam, jpegs = recording_jpegs(mission, cfg, n)
    return measure_choices(jpegs, cam, (cfg.out_height, cfg.out_width))


def recording_jpegs(mission: Path, cfg: IngestConfig, n: int) -> tuple[RawCamera, list[bytes]]:
    """The first `n` JPEG payloads of the recording's first camera and that camera."""
    bags = [BagFile(p, mission) for p in find_bags(mission)]
    calib = read_static(bags, cfg)
    cam_name = next(iter(calib.cameras))
    topic = cfg.topics.image_topic(cam_name)
    jpegs: list[bytes] = []
    for bag in bags:
        for msg in bag.messages([topic]):
            jpegs.append(bytes(np.asarray(bag.deserialize(msg).data, dtype=np.uint8)))
            if len(jpegs) >= n:
                break
        bag.close()
    return calib.cameras[cam_name], jpegs


def _judged(cfg: IngestConfig) -> IngestConfig:
    """`cfg` with every message judged by the checks (chunk checksums not trusted)."""
    checks = cfg.checks.model_copy(update={"trust_checksums": False})
    return cfg.model_copy(update={"checks": checks})


def run_ingest_bench(
    seconds: float = 12.0, gt_seconds: float = 3.0, workdir: Path | None = None
) -> dict[str, Any]:
    """Run the benchmark; JSON-ready dict.

    Time ratio on a GrandTour-sized recording (1920x1280 front camera, `gt_seconds`) and on a
    default synthetic one (480x320, three cameras, `seconds`); RSS on `seconds` and 2x`seconds`.
    """
    cfg = IngestConfig()
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        root = Path(tmp)
        big = make_recording(root / "rec", gt_seconds, image_width=1920, image_height=1280,
                             cameras=["front"], depth_maps=False)  # fmt: skip
        big_cfg = IngestConfig(cameras=["front"])
        timing_big = timed_ratio(big, root / "out_big", big_cfg)
        timing_judged = timed_ratio(big, root / "out_judged", _judged(big_cfg))
        timing_hf = timed_ratio(_hf_copy(big, root / "hf"), root / "out_hf",
                                IngestConfig(cameras=["front"]), floor=hf_floor_seconds)
        short = make_recording(root / "rec", seconds, depth_maps=False)
        long = make_recording(root / "rec", 2 * seconds, depth_maps=False)
        timing_small = timed_ratio(short, root / "out_small", cfg)
        timing_small_judged = timed_ratio(short, root / "out_small_judged", _judged(cfg))
        result = ingest_recording(short, root / "out_small", cfg)
        rss_1 = peak_rss_mb(short, root / "out_rss1", cfg)
        rss_2 = peak_rss_mb(long, root / "out_rss2", cfg)
        hf_rss = [peak_rss_mb(_hf_copy(m, root / "hf", cfg.cameras), root / f"out_hf_rss{i}", cfg)
                  for i, m in enumerate((short, long))]  # fmt: skip
        rec_choices = _recording_choices(short, cfg)
    return {
        "ingest_over_floor": timing_big["ratio"],
        "rss_ratio_2x_length": rss_2["peak_mb"] / rss_1["peak_mb"],
        "ingest_over_floor_small_images": timing_small["ratio"],
        "ingest_over_floor_judged": timing_judged["ratio"],
        "ingest_over_floor_small_images_judged": timing_small_judged["ratio"],
        "hf_ingest_over_floor": timing_hf["ratio"],
        "hf_over_bag_ingest": timing_hf["ingest_cpu_s"] / timing_big["ingest_cpu_s"],
        "timing_hf_grandtour_size": timing_hf,
        "hf_rss_ratio_2x_length": hf_rss[1]["peak_mb"] / hf_rss[0]["peak_mb"],
        "hf_peak_rss_mb_L": hf_rss[0]["peak_mb"],
        "hf_peak_rss_mb_2L": hf_rss[1]["peak_mb"],
        "hf_rss_increment_mb_L": hf_rss[0]["peak_mb"] - hf_rss[0]["base_mb"],
        "hf_rss_increment_mb_2L": hf_rss[1]["peak_mb"] - hf_rss[1]["base_mb"],
        "timing_grandtour_size": timing_big,
        "timing_small_images": timing_small,
        "timing_grandtour_size_judged": timing_judged,
        "timing_small_images_judged": timing_small_judged,
        "images_small": sum(result.images.values()),
        "sweeps_small": result.sweeps,
        "seconds_L": seconds,
        "peak_rss_mb_L": rss_1["peak_mb"],
        "peak_rss_mb_2L": rss_2["peak_mb"],
        "rss_increment_mb_L": rss_1["peak_mb"] - rss_1["base_mb"],
        "rss_increment_mb_2L": rss_2["peak_mb"] - rss_2["base_mb"],
        "decode_choices_recording": rec_choices,
        "decode_choices_grandtour_size": grandtour_choices(),
    }


if __name__ == "__main__":
    print(json.dumps(run_ingest_bench(), indent=2))
