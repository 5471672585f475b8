"""The smoke's held-out gate: a model's contact timing on its own frame and on another episode's.

`score_part` takes the decoded frames of a split part (`decode_part`: a seeded subsample of at
most `GateConfig.max_frames`; the smoke decodes them beside training), runs the model's
RGB-to-tactile on each frame's own RGB, on the RGB of a random frame of another episode of the
part (rgb_pretrain.partners, "shuffled": the test-part controls' pairing) and on the RGB of
another episode's frame at the same relative moment (the phase-matched control:
`phase_partners`), and keeps per frame what handtouch.bench.timing needs
(the contact label, the predicted contact mass, the squared errors, the frame and its relative
position). `gate` turns the tables of the parts into the checks and the report:

    test   every frame of the test part: the gate's checks, required (in-distribution), but the
           phase-matched one, reported: the test part holds one episode per task, and their timings
           may coincide (seed 0: a clock fitted on those six episodes scored 0.83, the phase-matched
           control 0.86), which says nothing about the model;
    ood    the held-out task's frames: the gate's checks, required;
    stress the stress task's frames (held out too; shares no touch with a training task):
           the same checks, reported only;
the checks being: contact-timing AUROC >= the floor, >= the mis-paired control's + the gap,
>= the phase-matched control's + the gap, and the lag checks (predicted and measured contact agree
best within +-2 frames of no shift, over shifts of +-1 s, and there clearly better than 0.5 s away). Reported beside them: the clock
reference (P(contact | tenth of the episode) measured on the test part: what reading no image at
all scores), and held-out F-RMSE per frame, pooled and on contact frames against the better of
all zeros and the mis-paired model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from htdata.read import keys
from htdata.read.itemoptions import ItemOptions
from htdata.read.metadata import DatasetMetadata
from htdata.read.torchdata import TactileFrameDataset

from .bench.items import subsample
from .bench.timing import (
    LAG_SIDE_S,
    LAG_SPAN_S,
    PHASE_MATCHED,
    FrameTable,
    contact_mass,
    contact_streams,
    has_contact,
    lag_check,
    lag_curve,
    lag_peak_check,
    position_clock,
    rmse_report,
    timing_checks,
    timing_scores,
)
from .rgb_encoder import model_rgb_features
from .rgb_pretrain import episode_fps, partners


@dataclass
class GateConfig:
    # Frames per part (a seeded subsample): the smoke's ood part (two held-out tasks) has ~1,240 and
    # test ~650; a frame costs two RGB-to-tactile passes. 800 keeps ~350 frames of the held-out task.
    max_frames: int = 800
    seed: int = 0
    batch_size: int = 32


_IDS = (keys.HAND, keys.EPISODE, keys.FRAME, keys.TASK)


def decode_part(dataset_root, split: str, part: str, cfg: GateConfig) -> dict[str, torch.Tensor]:
    """The part's subsampled frames, written item by item into preallocated compact tensors (RGB uint8,
    maps float16, coverage uint8): no batch stacking, a third of float32's memory traffic."""
    ds = TactileFrameDataset(str(dataset_root), options=ItemOptions(split=split, part=part))
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


def phase_partners(episode: np.ndarray, task: np.ndarray, position: np.ndarray, seed: int = 0) -> np.ndarray:
    """For each frame, the row of another episode's frame at the nearest relative position (-1: none).

    Each episode gets one partner episode, drawn (seeded) among the other episodes of its task in the
    rows, or among all other episodes when its task has no other; then each frame the partner's frame
    nearest its relative position."""
    rng = np.random.default_rng([seed, 45])
    out = np.full(len(episode), -1, np.int64)
    episodes = np.unique(episode)
    task_of = {int(e): task[np.flatnonzero(episode == e)[0]] for e in episodes}
    for e in episodes:
        same = [o for o in episodes if o != e and task_of[int(o)] == task_of[int(e)]]
        pool = same or [o for o in episodes if o != e]
        if not pool:
            continue
        theirs = np.flatnonzero(episode == rng.choice(pool))
        mine = np.flatnonzero(episode == e)
        nearest = np.abs(position[mine][:, None] - position[theirs][None, :]).argmin(1)
        out[mine] = theirs[nearest]
    return out


def score_part(model, dataset_root, split: str, part: str, cfg: GateConfig | None = None,
               frames: dict[str, torch.Tensor] | None = None) -> FrameTable:
    """The FrameTable of one part: each frame scored on its own RGB, on another episode's at a random
    moment and on another episode's at the same relative moment. `frames`: the part's
    `decode_part(dataset_root, split, part, cfg)`, decoded earlier (the smoke does it beside training)."""
    cfg = cfg or GateConfig()
    flat = decode_part(dataset_root, split, part, cfg) if frames is None else frames
    meta = DatasetMetadata(dataset_root)
    episode, frame = flat[keys.EPISODE].numpy(), flat[keys.FRAME].numpy()
    lengths = np.array([max(int(ep.get("num_frames") or 0), 1) for ep in meta.episodes])
    position = (frame + 0.5) / lengths[episode]
    task_of_row = flat[keys.TASK].numpy()
    src = partners(episode, frame, episode_fps(dataset_root)[episode], "shuffled", seed=cfg.seed)
    phase_src = phase_partners(episode, task_of_row, position, cfg.seed)
    keep = np.flatnonzero((src >= 0) & (phase_src >= 0))   # a part of one episode has no other to pair with
    if len(keep) == 0:
        raise SystemExit(f"contact gate: part {part!r} of split {split!r} has one episode; "
                         "the mis-paired and phase-matched controls need two")
    task_names = np.array(meta.manifest["tasks"])
    mass = {p: np.zeros(len(keep)) for p in ("aligned", "mispaired", PHASE_MATCHED)}
    sq = {p: np.zeros(len(keep)) for p in ("aligned", "mispaired", PHASE_MATCHED, "zeros")}
    label, count = np.zeros(len(keep), bool), np.zeros(len(keep))
    if isinstance(model, torch.nn.Module):
        model.eval()
    with torch.inference_mode():
        features = model_rgb_features(model, flat[keys.RGB], cfg.batch_size)
        for s in range(0, len(keep), cfg.batch_size):
            rows = slice(s, s + cfg.batch_size)
            i = torch.from_numpy(keep[rows])
            tac, cov = flat[keys.TACTILE][i].float(), flat[keys.COVERAGE][i].float()
            hand = flat[keys.HAND][i]
            label[rows] = has_contact(tac, cov).numpy()
            count[rows] = cov.flatten(1).sum(1).double().numpy()
            sq["zeros"][rows] = (tac.pow(2) * cov).flatten(1).sum(1).double().numpy()
            for pairing, rgb_rows in (("aligned", i), ("mispaired", torch.from_numpy(src[keep[rows]])),
                                      (PHASE_MATCHED, torch.from_numpy(phase_src[keep[rows]]))):
                rgb = flat[keys.RGB][rgb_rows]
                pred = (model.rgb_to_tactile(rgb, cov, hand) if features is None else
                        model.rgb_to_tactile(rgb, cov, hand, features=features[rgb_rows])).float()
                mass[pairing][rows] = contact_mass(pred, cov).double().numpy()
                sq[pairing][rows] = ((pred - tac).pow(2) * cov).flatten(1).sum(1).double().numpy()
    return FrameTable(episode[keep], flat[keys.HAND].numpy()[keep], task_names[task_of_row[keep]],
                      label, count, mass, sq, frame[keep], position[keep])


def gate(tables: dict[str, FrameTable], ood_task: str, stress_task: str | None,
         fps: float = 30.0) -> tuple[list[dict], dict]:
    """-> (checks, report) from the tables of the test and ood parts (module docstring); `fps` turns the
    lag check's +-LAG_SPAN_S into frames and its finding into seconds."""
    groups = {"test": (tables["test"], True, "test")}
    groups["ood"] = (tables["ood"].of_tasks([ood_task]), True, f"held-out (ood) {ood_task}")
    if stress_task:
        groups["stress"] = (tables["ood"].of_tasks([stress_task]), False, f"held-out stress test {stress_task}")
    test = tables["test"].select(contact_streams(tables["test"].episode, tables["test"].hand, tables["test"].label))
    clock = position_clock(test.position, test.label) if test.position is not None and len(test) else None
    span, side = max(1, round(LAG_SPAN_S * fps)), max(1, round(LAG_SIDE_S * fps))
    checks, report = [], {}
    for name, (table, required, where) in groups.items():
        scores = timing_scores(table, clock)
        checks += timing_checks(scores, where, required, phase_required=required and name != "test")
        entry = {"where": where, "required": required, "timing": scores, "rmse": rmse_report(table),
                 "clock": None if clock is None else clock.tolist()}
        if table.frame is not None:     # each part's curve: its peak required, its best shift reported
            entry["lag"] = lag_curve(table, span, side)
            checks += [lag_check(entry["lag"], where, fps, required=False),
                       lag_peak_check(entry["lag"], where, fps, required)]
        report[name] = entry
    gated = [groups[g][0] for g in ("test", "ood")]
    if all(t.frame is not None for t in gated):   # the lag is the pipeline's: its check pools the gated streams
        where = f"test and {groups['ood'][2]}"
        report["lag"] = {"where": where, "curve": lag_curve(FrameTable.concat(*gated), span, side)}
        checks.append(lag_check(report["lag"]["curve"], where, fps, required=True))
    return checks, report
