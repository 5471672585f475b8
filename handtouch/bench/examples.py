"""The windows HT-Bench's predictions figure shows: those with the most contact, with every track's output.

`collect_examples` feeds handtouch.bench.report.render_predictions.
"""

from __future__ import annotations

import numpy as np
import torch

from handtouch.api import TactileModel
from handtouch.bench.items import EvalConfig, EvalPart, PreparedPart, prepare_part
from htdata.errors import ArgumentError


def contact_order(windows: list[dict]) -> np.ndarray:
    """Prepared window positions ordered by ground-truth contact at T (sum over covered
    pixels), largest first; ties keep the lower position (stable, deterministic)."""
    totals = [(b["target"].float() * b["coverage"].float()).flatten(1).sum(1) for b in windows]
    if not totals:
        return np.zeros(0, np.int64)
    return np.argsort(-torch.cat(totals).double().numpy(), kind="stable")


def collect_examples(model: TactileModel, part: EvalPart | PreparedPart, count: int = 4,
                     cfg: EvalConfig | None = None) -> dict[str, np.ndarray]:
    """The `count` evaluation windows with the most contact at frame T, with every track's
    output, for report.render_predictions (frames without contact show nothing).

    `part` is a PreparedPart (its items) or an EvalPart (prepared first with `cfg`).
    Returns float32 arrays (N,224,224) for gt, inpaint, rgb2tactile, prediction,
    mask, coverage and uint8 rgb (N,224,224,3).
    """
    prep = part if isinstance(part, PreparedPart) else prepare_part(part, (cfg or EvalConfig()).validate())
    if not prep.windows:
        raise ArgumentError("collect_examples needs window items (the part has no windows)")
    sizes = [len(b["target"]) for b in prep.windows]
    starts = np.cumsum([0, *sizes])
    picks = contact_order(prep.windows)[:count]
    batch_of = np.searchsorted(starts, picks, side="right") - 1

    def gather(key: str) -> torch.Tensor:
        return torch.stack([prep.windows[k][key][i - starts[k]] for k, i in zip(batch_of, picks)])

    rgb_w, tac_w, hand = gather("rgb_window"), gather("tactile_window").float(), gather("hand")
    cov_t, target, mask = gather("coverage").float(), gather("target").float(), gather("mask").float()
    rgb_t = rgb_w[:, -1]
    if isinstance(model, torch.nn.Module):
        model.eval()
    with torch.inference_mode():
        inp = model.inpaint(target * (1 - mask), cov_t, mask, rgb_t, hand)
        r2t = model.rgb_to_tactile(rgb_t, cov_t, hand)
        nxt = model.predict_next(rgb_w, tac_w, cov_t, hand)
    rgb_np = rgb_t.float()
    if rgb_t.dtype != torch.uint8:
        rgb_np = rgb_np * 255.0
    return {
        "rgb": rgb_np.clamp(0, 255).round().to(torch.uint8).permute(0, 2, 3, 1).numpy(),
        "gt": target[:, 0].numpy(),
        "inpaint": inp.float()[:, 0].numpy(),
        "rgb2tactile": r2t.float()[:, 0].numpy(),
        "prediction": nxt.float()[:, 0].numpy(),
        "mask": mask[:, 0].numpy(),
        "coverage": cov_t[:, 0].numpy(),
    }
