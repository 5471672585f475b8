"""Two CPU processes (gloo) train a few steps; both ranks must end bit-identical."""

import json
import os
import socket
import time

import torch
import torch.multiprocessing as mp
from torch.utils.data import Dataset

from handtouch.config import ModelConfig, StageConfig, train_config_from_dict
from handtouch.distributed import init_distributed, unwrap, wrap
from handtouch.model import HandTouch
from handtouch.rgb_encoder import load_rgb_encoder
from handtouch.stages import Reconstruction, StageLoss
from handtouch.train import TrainData, evaluate_heldout, heldout_batch, train

JOIN_TIMEOUT_S = 240      # a deadlocked collective must fail the test, never hang the suite

TINY = dict(encoder="vit", patch=32, dim=32, depth=1, heads=2, mlp_ratio=2.0, code_dim=8, codebook_size=16,
            vq_usage_decay=0.5, decoder_depth=1, decoder_channels=16, fusion_depth=1, temporal_depth=1,
            predictor_depth=1)


class TinyFrames(Dataset):
    """Deterministic in-memory items with the TactileFrameDataset keys (window=None) or windows."""

    def __init__(self, n: int, window: int | None = None):
        self.n, self.window = n, window

    def __len__(self):
        return self.n

    def _frame(self, i):
        g = torch.Generator().manual_seed(1000 + i)
        return torch.rand(1, 224, 224, generator=g) ** 4, torch.randint(0, 256, (3, 224, 224), generator=g,
                                                                        dtype=torch.uint8)

    def __getitem__(self, i):
        regions = torch.zeros(224, 224, dtype=torch.uint8)
        regions[:100] = 2
        regions[100:] = 6
        item = {"coverage": torch.ones(1, 224, 224), "regions": regions, "hand": torch.tensor(i % 2),
                "task": torch.tensor(0), "scene": torch.tensor(0)}
        if self.window is None:
            item["tactile"], item["rgb"] = self._frame(i)
        else:
            frames = [self._frame(i + k) for k in range(self.window)]
            item["tactile"] = torch.stack([f[0] for f in frames])
            item["rgb"] = torch.stack([f[1] for f in frames])
        return item


def _worker(rank: int, world: int, port: int, out: str) -> None:
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank),
                      WORLD_SIZE=str(world), LOCAL_RANK=str(rank))
    torch.set_num_threads(1)
    env = init_distributed("cpu")
    torch.manual_seed(0)
    model = HandTouch(ModelConfig(**TINY), load_rgb_encoder("random:0"))
    stage = Reconstruction(StageConfig(trainable=["encoder", "vq", "decoder"]))
    stage.configure(model)
    model.train()
    ddp = wrap(StageLoss(stage, model), env)
    opt = torch.optim.AdamW([p for p in model.parameters() if p.requires_grad], lr=1e-3)
    data = TinyFrames(8)
    restarts = []
    for step in range(3):
        items = [data[(2 * step + rank) % 8], data[(2 * step + rank + 4) % 8]]   # different data per rank
        batch = torch.utils.data.default_collate(items)
        loss, terms = ddp(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        restarts.append(float(terms["restarts"]))
    torch.save({"state": unwrap(ddp).model.state_dict(), "restarts": restarts}, os.path.join(out, f"rank{rank}.pt"))

    # Rank 0 alone evaluates a model left in training mode while rank 1 goes straight to a
    # barrier: any collective inside evaluation (VQ usage all_reduce, restart broadcast)
    # would deadlock here, as it once did in a full-suite run.
    model.train()
    if rank == 0:
        evaluate_heldout(model, heldout_batch(TinyFrames(4), 4), env.device)
        assert not model.training
    torch.distributed.barrier()

    cfg = train_config_from_dict({
        "data_root": "in-memory", "out_dir": os.path.join(out, "run"), "rgb_encoder": "random:0",
        "device": "cpu", "workers": 0, "batch_size": 2, "eval_batch_size": 2, "log_every": 2,
        "checkpoint_every": 100, "model": TINY,
        "stage1": {"steps": 3, "lr": 1e-3, "warmup_steps": 1, "trainable": ["encoder", "vq", "decoder"]},
        "stage2": {"steps": 2, "lr": 1e-3, "warmup_steps": 1,
                   "trainable": ["encoder", "vq", "decoder", "rgb_proj", "hand_token", "fusion"]},
        "stage3": {"steps": 2, "lr": 1e-3, "warmup_steps": 1,
                   "trainable": ["temporal", "predictor", "rgb_proj", "hand_token", "vq", "decoder"]}})
    frames = TinyFrames(8)
    train(cfg, TrainData(frames, TinyFrames(6, window=3), frames, "in-memory frames"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _join_or_fail(ctx, timeout_s: float) -> None:
    """Join spawned ranks; on timeout kill them and fail (a hung rank must not hang pytest)."""
    deadline = time.monotonic() + timeout_s
    while not ctx.join(timeout=max(0.1, min(5.0, deadline - time.monotonic()))):
        if time.monotonic() >= deadline:
            for p in ctx.processes:
                if p.is_alive():
                    p.kill()
            for p in ctx.processes:
                p.join(5)
            raise AssertionError(f"DDP ranks did not finish within {timeout_s} s (deadlock?)")


def test_two_process_ddp_ranks_stay_identical(tmp_path):
    ctx = mp.spawn(_worker, args=(2, _free_port(), str(tmp_path)), nprocs=2, join=False)
    _join_or_fail(ctx, JOIN_TIMEOUT_S)     # a rank that raised re-raises here (ProcessRaisedException)
    r0 = torch.load(tmp_path / "rank0.pt", weights_only=True)
    r1 = torch.load(tmp_path / "rank1.pt", weights_only=True)
    assert r0["restarts"][0] == 16                      # the first step restarts every code ...
    assert r0["restarts"] == r1["restarts"]             # ... identically on both ranks
    assert r0["state"].keys() == r1["state"].keys()
    for k in r0["state"]:
        assert torch.equal(r0["state"][k], r1["state"][k]), k
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["world_size"] == 2
    assert set(metrics["stages"]) == {"1", "2", "3"}
    s1 = metrics["stages"]["1"]
    assert abs(s1["samples_per_s"] - 2 * 2 * s1["steps_per_s"]) < 1e-6 * s1["samples_per_s"]
