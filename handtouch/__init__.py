"""HandTouch: a thin vision-tactile trainer that proves htdata shards train end to end.

    api.py            the interface every model scored by HT-Bench implements
    config.py         dataclass configs of the model and trainer, from TOML
    resources.py      where the training configs (`configs/*.toml`) live
    model.py          HandTouch: tactile encoder -> fusion / temporal prediction -> factorised VQ -> decoder
    encoders.py       tactile encoders: (B, C, 224, 224) -> tokens (B, N, D)
    rgb_encoder.py    the frozen RGB encoder, chosen by a spec string; never downloads
    vq.py             factorised vector quantiser (usage EMA, dead-code restarts)
    decoder.py        tokens -> tactile map (B, 1, 224, 224) in [0, 1]
    masking.py        stage-2 masks: anatomical parts or complete, on a curriculum
    stages.py         the training stages, one object each: inputs, batch, loss
    steploop.py       one stage's steps, no host sync between logs, where the time goes
    train.py          the trainer: stage 1 (reconstruct) -> 2 (masked + RGB) -> 3 (predict t_T)
    checkpoint.py     stage checkpoints, written atomically, resumed exactly
    distributed.py    one process or torchrun (DDP)
    progress.py       a progress line every few seconds (the smoke's heartbeat), and its phase timer
    smoke.py          the end-to-end smoke run (`make train-smoke`)
    smokedata.py      the smoke's data: corpus, dataset, split (a held-out task + a stress task), leak check
    smokechecks.py    the smoke's checks of what HandTouch learned, and its exit status
    smokeprep.py      the smoke's evaluation inputs and control probe, built in a second process beside training
    contact_gate.py   the held-out gate: contact timing on a frame's own RGB and on another episode's
    compare.py        the paper's comparison of encoders on HT-Bench
    rgb_pretrain.py   an RGB encoder trained on the run's data, and the misalignment control
    probeitems.py     the RGB probes' items: a part's frames pooled and reduced to what a probe reads
    rgb2t_sweep.py    stage-2/3 experiments on the RGB-to-tactile track from one stage-1 checkpoint
    task_transfer.py  leave-one-task-out RGB probes: which held-out tasks can RGB predict touch for
    benchmark.py      the `htdata bench` section "training": stage 1 steps/s, fp32 vs bf16
    gpucheck.py       `make gpu-check`: stage 1 on a CUDA GPU, fed by the real loader
    bench/            HT-Bench: the tracks, their metrics and report

May import: htdata (the reader, the torch datasets, the split rule, its errors), torch and the
training extras. htdata never imports handtouch (its bench section is an entry point).
"""

import os

# Idle OpenMP threads sleep instead of spinning: on a busy machine the smoke's two threads spent their
# time waiting on each other (19-21 samples/s against 115-260; docs/HANDTOUCH.md, "How long it takes").
# The arithmetic, and so the weights, are the same. Read when torch loads, so set before any import of it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

