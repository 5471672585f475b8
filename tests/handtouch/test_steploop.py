"""The trainer's step loop reads nothing back per step; `make gpu-check` without a GPU (handtouch/steploop.py, gpucheck.py)."""

import math

import pytest
import torch

from handtouch import gpucheck
from handtouch.steploop import StepTimes, _Window
from tests.factories.model import frame_batch, make_stage, tiny_model


class ReadBack(AssertionError):
    pass


@pytest.fixture
def no_read_back(monkeypatch):
    """Any read of a tensor value on the host (what stops a GPU until it catches up) raises."""
    def refuse(name):
        def method(self, *a, **k):
            raise ReadBack(f"Tensor.{name} called during a training step")
        return method
    for name in ("item", "tolist", "__bool__", "__int__", "__float__", "__index__"):
        monkeypatch.setattr(torch.Tensor, name, refuse(name))


def test_stage1_step_and_vq_bookkeeping_read_nothing_back(no_read_back):
    model = tiny_model().train()     # usage 0: the first training step restarts every code
    stage = make_stage(1)
    stage.configure(model)
    window = _Window(torch.device("cpu"))
    for step in range(3):
        loss, terms = stage.loss(model, frame_batch(b=2, seed=step))
        loss.backward()
        window.add(step, loss, terms)
    assert window.steps == 3


def test_window_means_and_non_finite_loss_named_at_the_log():
    window = _Window(torch.device("cpu"))
    window.add(0, torch.tensor(1.0), {"recon": torch.tensor(2.0)})
    window.add(1, torch.tensor(3.0), {"recon": torch.tensor(4.0)})
    assert window.read(1) == {"loss": 2.0, "recon": 3.0}
    window.add(2, torch.tensor(1.0), {"recon": torch.tensor(1.0)})
    window.add(3, torch.tensor(math.nan), {"recon": torch.tensor(1.0)})
    window.add(4, torch.tensor(math.inf), {"recon": torch.tensor(1.0)})
    with pytest.raises(FloatingPointError, match="stage 1 step 3: non-finite loss"):
        window.read(1)


def test_step_times_shares_on_cpu():
    times = StepTimes(steps=4, wall_s=2.0, data_wait_s=0.5, host_s=1.5)
    d = times.as_dict()
    assert d["data_wait_share"] == 0.25 and "device_s" not in d


def test_gpu_check_exits_with_a_clear_message_without_a_gpu(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert gpucheck.main(["--work", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "no CUDA device" in err and "nothing measured" in err


def test_gpu_check_settings_are_stage1_of_the_full_config(tmp_path):
    cfg = gpucheck.setting_config(tmp_path / "ds", tmp_path / "out", 128, 16, 300, False)
    assert cfg.stages == [1] and cfg.batch_size == 128 and cfg.workers == 16 and cfg.bf16 and not cfg.compile
    assert cfg.model.dim == 384 and cfg.model.depth == 8 and cfg.model.codebook_size == 2048   # full.toml's model
    assert cfg.stage1.steps == 300 and cfg.device == "cuda" and cfg.split == gpucheck.SPLIT


def test_heartbeat_names_the_phase_and_the_latest_progress():
    from handtouch.progress import Heartbeat, Rate

    lines = []
    beat = Heartbeat(every_s=0.05, emit=lines.append)
    with beat:
        beat.phase("train_vit")
        beat.report(Rate().report("stage 1", 3, 10, 8))
        import time
        time.sleep(0.3)
        beat.phase("eval_handtouch-vit")
        time.sleep(0.2)
    assert any(line.startswith("smoke: train_vit ") and "stage 1 step 3/10" in line and "samples/s" in line
               and "ETA" in line for line in lines)
    assert lines[-1].startswith("smoke: eval_handtouch-vit ") and "step" not in lines[-1]


def test_the_gpu_check_ingests_every_source_of_the_sample_corpus(tmp_path, monkeypatch):
    """Its formats are the corpus's list, not a copy of it (htdata.synthetic.corpus.FORMATS)."""
    from htdata.synthetic.corpus import FORMATS

    assert gpucheck.sample_formats() == FORMATS
    started = []

    class Done:
        def __init__(self, argv, **kw):
            started.append(argv[argv.index("--formats") + 1])

        def wait(self):
            return 0

    monkeypatch.setattr(gpucheck.subprocess, "Popen", Done)
    raws = gpucheck._sample_formats(tmp_path, "tiny")
    assert tuple(started) == tuple(raws) == FORMATS and raws[FORMATS[0]] == tmp_path / f"raw_{FORMATS[0]}" / FORMATS[0]
