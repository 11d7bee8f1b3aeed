"""What the image checks see of JPEG damage that decodes without an error, and whether a
per-MCU comparison with the neighbouring frames could see the rest.

The JPEG frames of a small synthetic mission (Hugging Face layout: one file per frame) get 1 to
3 flipped bits in their entropy-coded data; each damaged frame that still decodes is classified
(no visible change; < 20 pixels off by more than 16 levels; caught by `drift_problem`; missed).
`refused_only_by_strict_decode` counts the undecodable frames that a decode ignoring libjpeg's
warnings (corrupt data, premature end, bad Huffman code) would have handed on.
For the missed ones and for every clean frame, the per-MCU score
max over cells of |img - (a + b) / 2| - k |a - b| (a, b: the neighbouring frames, YCbCr means
per MCU) says whether a threshold could separate damage from motion: it could only if the
clean frames' highest score lay below most damaged ones.

Run: `python -m bench.image_damage [--cases N]` (prints JSON).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import simplejpeg

from pipeline.ingest.checks.image_checks import Cells, cell_means, cell_size, drift_problem

STEP_Z, BLIP_LEVELS, GAP_S = 10.0, 10.0, 1.0
"""The image checks' defaults (`ingest.checks`)."""


def frames(folder: Path) -> tuple[list[bytes], list[np.ndarray], list[Cells], tuple[int, int]]:
    """(JPEG bytes, decoded RGB, per-MCU means, MCU size) of a folder of numbered frames."""
    raw = [p.read_bytes() for p in sorted(folder.glob("*.jpeg"))]
    dec = [simplejpeg.decode_jpeg(r) for r in raw]
    cs = cell_size(simplejpeg.decode_jpeg_header(raw[0])[3], 1)
    return raw, dec, [Cells(i * 100_000_000, cell_means(d, cs)) for i, d in enumerate(dec)], cs


def mcu_score(img: Cells, a: Cells, b: Cells, k: float) -> float:
    """Largest per-MCU disagreement of `img` with the mean of its neighbours, less k times
    theirs with each other (motion)."""
    r = np.abs(img.means - (a.means + b.means) / 2)
    return float((r - k * np.abs(a.means - b.means)).max())


def flip(raw: bytes, rng: np.random.Generator) -> bytes:
    """1 to 3 flipped bits in the entropy-coded data (after the SOS header)."""
    data = bytearray(raw)
    start = data.find(b"\xff\xda") + 20
    for _ in range(int(rng.integers(1, 4))):
        data[int(rng.integers(start, len(data) - 2))] ^= 1 << int(rng.integers(0, 8))
    return bytes(data)


def _decodes_lax(data: bytes) -> int:
    """1 when libjpeg decodes `data` with its warnings ignored (as OpenCV's imdecode does)."""
    try:
        simplejpeg.decode_jpeg(data, strict=False)
    except ValueError:
        return 0
    return 1


def run_image_damage(cases: int = 400, k: float = 1.0, seed: int = 0) -> dict[str, Any]:
    """The classification of `cases` damaged frames and the score distributions (see above)."""
    from pipeline.synth.api import synthesize
    from schemas.config import SynthConfig

    with tempfile.TemporaryDirectory() as tmp:
        cfg = SynthConfig(seed=3, seconds=3.0, format="hf-zarr", depth_maps=False)
        synthesize(Path(tmp), cfg, "corridor", "m")
        images = Path(tmp) / "m" / "images"
        cams = {p.name: frames(p) for p in sorted(images.iterdir())}
    clean = [mcu_score(c[i], c[i - 1], c[i + 1], k) for _, _, c, _ in cams.values()
             for i in range(1, len(c) - 1)]  # fmt: skip
    raw, dec, cells, cs = cams["hdr_front"]
    rng = np.random.default_rng(seed)
    out = {"undecodable": 0, "no_visible_change": 0, "under_20_px": 0, "caught": 0, "missed": 0,
           "refused_only_by_strict_decode": 0}
    missed = []
    for _ in range(cases):
        i = int(rng.integers(1, len(raw) - 1))
        damaged = flip(raw[i], rng)
        try:
            d = simplejpeg.decode_jpeg(damaged, strict=True)
        except ValueError:
            out["undecodable"] += 1
            out["refused_only_by_strict_decode"] += _decodes_lax(damaged)
            continue
        px = int((np.abs(d.astype(int) - dec[i].astype(int)).max(axis=2) > 16).sum())
        img = Cells(i * 100_000_000, cell_means(d, cs))
        near = [cells[i - 1], cells[i + 1]]
        if px == 0:
            out["no_visible_change"] += 1
        elif drift_problem(img, near, STEP_Z, BLIP_LEVELS, GAP_S):
            out["caught"] += 1
        elif px < 20:
            out["under_20_px"] += 1
        else:
            out["missed"] += 1
            missed.append(mcu_score(img, near[0], near[1], k))
    top = max(clean)
    return {**out, "k": k, "clean_frames": len(clean), "clean_score_max": round(top, 1),
            "missed_score_median": round(float(np.median(missed)), 1) if missed else None,
            "missed_scoring_above_every_clean_frame": int(sum(m > top for m in missed))}


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--cases", type=int, default=400)
    parser.add_argument("--k", type=float, default=1.0)
    args = parser.parse_args()
    print(json.dumps(run_image_damage(args.cases, args.k), indent=1))
