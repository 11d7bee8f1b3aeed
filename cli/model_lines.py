"""What the model commands print: held-out scoring lines, the sampler's temperature, the
per-target and summary tables, the margin over the strongest baseline, the recipe hint, and the
sample PNGs `m3gd sample` writes (`cli.model` parses and calls; this module only formats).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.table import Table

if TYPE_CHECKING:
    from collections.abc import Callable

    from model.evaluate import TargetResult
    from model.runs import LoopSettings, TrainSetup

def score_lines(loop: LoopSettings, say: Callable[..., None]
                 ) -> Callable[[int, dict[str, Any] | None], None]:
    """What `m3gd train` says around a held-out scoring (`model.runs.run_training`'s
    on_score): a line before it starts (it takes a while) and its result after."""
    def on_score(step: int, scores: dict[str, Any] | None) -> None:
        if scores is None:
            say(f"scoring step {step} on the first {loop.eval_clips} eval clips (validation "
                f"loss, {loop.sample_steps}-step samples)...", highlight=False, soft_wrap=True)
            return
        say(f"held-out at step {step}: {held_out_line(scores)}", highlight=False,
            soft_wrap=True)
    return on_score


def held_out_line(scores: dict[str, Any]) -> str:
    """A held-out scoring (`model.scoring.held_out_scores`) in one line: validation loss, and
    the model's and the baselines' mean PSNR where the images could be decoded."""
    text = f"validation loss {scores['val_loss_mean']:.4f}"
    if "psnr_model" not in scores:
        return text + " (no PSNR: the cache's images cannot be decoded)"
    base = {k.removeprefix("psnr_"): v for k, v in scores.items()
            if k.startswith("psnr_") and k != "psnr_model"}
    parts = ", ".join(f"{BASELINE_LABELS.get(n, n)} {v:.2f}" for n, v in base.items())
    return (text + f"; PSNR on {scores['eval_clips']} clips: model {scores['psnr_model']:.2f}"
            f" dB" + (f" ({parts})" if parts else ""))


def sampler_lines(setup: TrainSetup) -> list[str]:
    """What `m3gd train` says of the sampler temperature its validation recordings chose
    (`model.runs.TrainSetup.sampler`), or why none was chosen; [] without them."""
    if not setup.val:
        return []
    b = setup.sampler
    if b is None:
        return [n for n in setup.notes if n.startswith("no sampler temperature")]
    psnr = ", ".join(f"T={t}: {p:.2f}" for t, p in b["val_psnr"].items())
    return [f"sampler temperature {b['temperature']:g}: the best {b['steps']}-step PSNR (dB) on "
            f"{b['clips']} clips of the validation recordings {', '.join(b['recordings'])} "
            f"({psnr}); recorded in the checkpoint, the default of m3gd sample and eval "
            f"(--temperature 1: the paper's)"]


BASELINE_LABELS = {"copy_source": "copy-nearest-source", "mean_latent": "mean latent",
                   "reprojection": "LiDAR reprojection",
                   "mean_image": "mean training image", "recording_mean": "recording mean",
                   "recording_mean_oracle": "recording mean (held-out views, reference only)"}
"""How `sample` and `eval` name the baselines (model.evaluate.BASELINES)."""


def target_table(results: list[TargetResult], ordinals: list[int]) -> Table:
    """Per-target scores: clip, target ordinal, view, PSNR, SSIM, and the baselines' PSNR."""
    from model.evaluate import BASELINES

    names = [n for n in BASELINES if any(n in r.baselines for r in results)]
    table = Table(title="target views")
    for col in ("clip", "target", "view", "PSNR dB", "SSIM", *(f"{n} dB" for n in names)):
        table.add_column(col, justify="right")
    for r, k in zip(results, ordinals, strict=True):
        base = [f"{r.baselines[n][0]:.2f}" if n in r.baselines else "-" for n in names]
        table.add_row(str(r.clip_id), str(k), str(r.view), f"{r.psnr:.2f}", f"{r.ssim:.3f}",
                      *base)
    return table


def margin_line(summary: dict[str, Any]) -> str:
    """The model against every baseline on the same targets, and its margins over the
    strongest of them all (PSNR and SSIM, `model.evaluate.RANKED_BASELINES`: the LiDAR
    reprojection included), one line; says so plainly when the model trails."""
    if "baselines" not in summary:
        return "no baseline (the clips carry no camera poses)"
    b = summary["baselines"]
    parts = [f"model {summary['psnr_mean']:.2f} dB / SSIM {summary['ssim_mean']:.3f}"]
    parts += [f"{BASELINE_LABELS.get(n, n)} {v['psnr_mean']:.2f} / {v['ssim_mean']:.3f}"
              for n, v in b.items()]
    if "strongest_baseline" in summary:
        top, top_ssim = summary["strongest_baseline"], summary["strongest_baseline_by_ssim"]
        margin, ssim_margin = summary["margin_strongest_db"], summary["ssim_margin_strongest"]
    else:  # a result written before every baseline was ranked
        top, top_ssim = summary["better_baseline"], summary["strongest_ssim_baseline"]
        margin, ssim_margin = summary["margin_db"], summary["ssim_margin"]
    verdict = ("beats every baseline" if margin > 0 and ssim_margin > 0 else
               "TRAILS the strongest baseline in " + " and ".join(
                   w for w, m in (("PSNR", margin), ("SSIM", ssim_margin)) if m <= 0))
    return ("; ".join(parts) + f"; margin over the strongest baseline "
            f"({BASELINE_LABELS.get(top, top)}) {margin:+.2f} dB, SSIM {ssim_margin:+.3f} "
            f"against {BASELINE_LABELS.get(top_ssim, top_ssim)}: {verdict}")


def recipe_hint(summary: dict[str, Any], settings: dict[str, Any]) -> str | None:
    """A line for a model below the better baseline: what a working recipe is, and, for
    draws of several steps at a temperature above 0, what the temperature costs in PSNR.
    settings: the scoring's (train_step, steps, temperature)."""
    margin = summary.get("margin_db")
    if margin is None or margin >= 0:
        return None
    from schemas.config import TrainConfig

    steps = TrainConfig().steps
    line = (f"below the {summary['better_baseline']} baseline after {settings['train_step']} "
            f"training steps: `m3gd train`'s defaults are the recipe measured to beat both "
            f"baselines ({steps} steps; docs/guides/trainers.md, 'The training recipe')")
    if settings.get("temperature", 1.0) > 0 and settings.get("steps", 1) > 1:
        line += (f"; at temperature {settings['temperature']:g} a {settings['steps']}-step "
                 f"sample is a draw, whose spread PSNR charges: --temperature 0 scores the "
                 f"deterministic point estimate (docs/guides/trainers.md, 'Accuracy or "
                 f"diversity')")
    return line


def ordinals(results: list[TargetResult]) -> list[int]:
    """Index of each result among the targets of its clip (0, 1, ...)."""
    count: dict[int, int] = {}
    out = []
    for r in results:
        out.append(count.get(r.clip_id, 0))
        count[r.clip_id] = out[-1] + 1
    return out


def write_samples(results: list[TargetResult], out: Path) -> Path:
    """PNG pairs <out>/samples/<clip_id>/target_<k>_{pred,gt}.png; returns the samples dir."""
    from PIL import Image

    root = out / "samples"
    for r, k in zip(results, ordinals(results), strict=True):
        where = root / str(r.clip_id)
        where.mkdir(parents=True, exist_ok=True)
        if r.pred is None or r.gt is None:
            raise ValueError(f"clip {r.clip_id}: no decoded image to save (encoder not loaded)")
        Image.fromarray(r.pred).save(where / f"target_{k}_pred.png")
        Image.fromarray(r.gt).save(where / f"target_{k}_gt.png")
    return root


def summary_table(summary: dict[str, Any]) -> Table:
    """Mean scores overall and per hard / other subset."""
    table = Table(title="eval")
    for col in ("subset", "targets", "PSNR dB mean", "PSNR dB median", "SSIM mean"):
        table.add_column(col, justify="left" if col == "subset" else "right")
    for name, row in [("all", summary), ("hard", summary.get("hard")),
                      ("not hard", summary.get("not_hard"))]:
        if row is not None:
            table.add_row(name, str(row["targets"]), f"{row['psnr_mean']:.2f}",
                          f"{row['psnr_median']:.2f}", f"{row['ssim_mean']:.3f}")
    return table
