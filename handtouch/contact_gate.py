"""The smoke's held-out gate: a model's contact timing on its own frame and on another episode's.

`score_part` decodes the frames of a split part (a seeded subsample of at most
`GateConfig.max_frames`), runs the model's RGB-to-tactile on each frame's own RGB and on the
RGB of a random frame of another episode of the part (rgb_pretrain.partners, "shuffled": the
test-part controls' pairing), and keeps per frame what handtouch.bench.timing needs (the
contact label, the predicted contact mass, the squared error of the model, of the mis-paired
model and of all zeros). `gate` turns the tables of the parts into the checks and the report:

    test   every frame of the test part: the gate's two checks, required (in-distribution);
    ood    the held-out task's frames: the gate's two checks, required;
    stress the stress task's frames (held out too; shares no touch with a training task):
           the same two checks, reported only;
and held-out F-RMSE per frame, pooled and on contact frames against the better of all zeros
and the mis-paired model, reported for ood and stress.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from htdata.read import keys
from htdata.read.metadata import DatasetMetadata
from htdata.read.torchdata import TactileFrameDataset

from .bench.items import subsample
from .bench.timing import FrameTable, contact_mass, has_contact, rmse_report, timing_checks, timing_scores
from .rgb_pretrain import episode_fps, partners


@dataclass
class GateConfig:
    # Frames per part (a seeded subsample): the smoke's ood part (two held-out tasks) has ~1,240 and
    # test ~650; a frame costs two RGB-to-tactile passes. 800 keeps ~350 frames of the held-out task.
    max_frames: int = 800
    seed: int = 0
    batch_size: int = 32


_IDS = (keys.HAND, keys.EPISODE, keys.FRAME, keys.TASK)


def _decode(dataset_root, split: str, part: str, cfg: GateConfig) -> dict[str, torch.Tensor]:
    """The part's subsampled frames, written item by item into preallocated compact tensors (RGB uint8,
    maps float16, coverage uint8): no batch stacking, a third of float32's memory traffic."""
    ds = TactileFrameDataset(str(dataset_root), split=split, part=part)
    if len(ds) < 2:
        raise SystemExit(f"contact gate: part {part!r} of split {split!r} has {len(ds)} frames; need >= 2")
    idx = subsample(len(ds), cfg.max_frames, cfg.seed)
    first = ds[int(idx[0])]
    n = len(idx)
    out = {keys.TACTILE: torch.empty((n, *first[keys.TACTILE].shape), dtype=torch.float16),
           keys.COVERAGE: torch.empty((n, *first[keys.COVERAGE].shape), dtype=torch.uint8),
           keys.RGB: torch.empty((n, *first[keys.RGB].shape), dtype=first[keys.RGB].dtype),
           **{k: torch.empty(n, dtype=torch.long) for k in _IDS}}
    for row, i in enumerate(idx):
        item = first if row == 0 else ds[int(i)]
        out[keys.TACTILE][row] = item[keys.TACTILE]
        out[keys.COVERAGE][row] = item[keys.COVERAGE] > 0.5
        out[keys.RGB][row] = item[keys.RGB]
        for k in _IDS:
            out[k][row] = int(item[k])
    return out


def score_part(model, dataset_root, split: str, part: str, cfg: GateConfig | None = None) -> FrameTable:
    """The FrameTable of one part: each frame scored on its own RGB and on another episode's."""
    cfg = cfg or GateConfig()
    flat = _decode(dataset_root, split, part, cfg)
    episode, frame = flat[keys.EPISODE].numpy(), flat[keys.FRAME].numpy()
    src = partners(episode, frame, episode_fps(dataset_root)[episode], "shuffled", seed=cfg.seed)
    keep = np.flatnonzero(src >= 0)     # a part of one episode has no other episode to pair with
    if len(keep) == 0:
        raise SystemExit(f"contact gate: part {part!r} of split {split!r} has one episode; "
                         "the mis-paired control needs two")
    task_names = np.array(DatasetMetadata(dataset_root).manifest["tasks"])
    mass = {p: np.zeros(len(keep)) for p in ("aligned", "mispaired")}
    sq = {p: np.zeros(len(keep)) for p in ("aligned", "mispaired", "zeros")}
    label, count = np.zeros(len(keep), bool), np.zeros(len(keep))
    if isinstance(model, torch.nn.Module):
        model.eval()
    with torch.inference_mode():
        for s in range(0, len(keep), cfg.batch_size):
            rows = slice(s, s + cfg.batch_size)
            i = torch.from_numpy(keep[rows])
            tac, cov = flat[keys.TACTILE][i].float(), flat[keys.COVERAGE][i].float()
            hand = flat[keys.HAND][i]
            label[rows] = has_contact(tac, cov).numpy()
            count[rows] = cov.flatten(1).sum(1).double().numpy()
            sq["zeros"][rows] = (tac.pow(2) * cov).flatten(1).sum(1).double().numpy()
            for pairing, rgb_rows in (("aligned", i), ("mispaired", torch.from_numpy(src[keep[rows]]))):
                pred = model.rgb_to_tactile(flat[keys.RGB][rgb_rows], cov, hand).float()
                mass[pairing][rows] = contact_mass(pred, cov).double().numpy()
                sq[pairing][rows] = ((pred - tac).pow(2) * cov).flatten(1).sum(1).double().numpy()
    return FrameTable(episode[keep], flat[keys.HAND].numpy()[keep], task_names[flat[keys.TASK].numpy()[keep]],
                      label, count, mass, sq)


def gate(tables: dict[str, FrameTable], ood_task: str, stress_task: str | None) -> tuple[list[dict], dict]:
    """-> (checks, report) from the tables of the test and ood parts (module docstring)."""
    groups = {"test": (tables["test"], True, "test")}
    groups["ood"] = (tables["ood"].of_tasks([ood_task]), True, f"held-out (ood) {ood_task}")
    if stress_task:
        groups["stress"] = (tables["ood"].of_tasks([stress_task]), False, f"held-out stress test {stress_task}")
    checks, report = [], {}
    for name, (table, required, where) in groups.items():
        scores = timing_scores(table)
        checks += timing_checks(scores, where, required)
        report[name] = {"where": where, "required": required, "timing": scores, "rmse": rmse_report(table)}
    return checks, report
