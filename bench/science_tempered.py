"""K-step sampling at a start-noise temperature chosen on the validation recordings.

The paper's sampler starts from z_1 ~ N(0, I) (temperature 1): a draw from the model, whose
spread a PSNR score pays for. A lower temperature (`model.sampler.sample`) trades that
spread for accuracy. Which temperature is a choice, so it is made where the suite makes its
other choices: on the validation recordings (`bench.science.val_recordings`, never scored
as eval). Each run scores its K-step samples there at every temperature of the grid, keeps
the one with the highest mean PSNR (the lowest temperature on a tie), and scores the eval
targets once at that temperature: `eval_k<K>_tval` beside the paper's `eval_k<K>`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bench.science import score
from model.temperature import TEMPERATURES, pick

__all__ = ["TEMPERATURES", "TEMPERING", "Tempering", "choose_temperature", "label", "pick"]

if TYPE_CHECKING:
    from pathlib import Path

    from bench.science import ScienceSpec
    from model.net import M3GDNet



@dataclass(frozen=True)
class Tempering:
    """Which K get a validation-chosen temperature, and the grid it is chosen from."""

    ks: tuple[int, ...] = (1, 10)
    temperatures: tuple[float, ...] = TEMPERATURES

    def labels(self) -> tuple[str, ...]:
        """The score keys these add beside eval_k<K>: '<K>_tval' (eval_k<K>_tval)."""
        return tuple(label(k) for k in self.ks)


TEMPERING = Tempering()
"""The suites' setting: K = 1 and K = 10 at the validation-chosen temperature."""


def label(k: int) -> str:
    """The key suffix of K-step samples at the validation-chosen temperature."""
    return f"{k}_tval"


def choose_temperature(net: M3GDNet, output_dir: Path, mode: str, spec: ScienceSpec,
                       k: int, temperatures: tuple[float, ...]) -> dict[str, Any]:
    """K-step PSNR (dB) on the validation recordings at each temperature, and the pick:
    {"temperature": T, "val_psnr": {str(T): dB}}."""
    val = {t: float(score(net, output_dir, mode, spec, k, spec.guidance, split="train",
                          temperature=t)["psnr_mean"]) for t in temperatures}
    return {"temperature": pick(val), "val_psnr": {str(t): p for t, p in val.items()}}
