"""The smoke's held-out gate scored in a forked process (handtouch.gatebeside): the checks and report
it sends back are the ones scored in this process, and its failure is named here."""

import argparse

import pytest

from handtouch.contact_gate import GateConfig, decode_part
from handtouch.gatebeside import GateJob
from handtouch.smokedata import SPLIT_NAME
from tests.factories import commit_split, episode_table, write_synthetic_dataset

EPISODES = episode_table(*[(f"s{i}", "seen", "lab", "R", 16) for i in range(4)],
                         *[(f"h{i}", "held", "lab", "R", 16) for i in range(4)])


class BrightnessModel:
    """Predicts touch from the frame's brightness: some numbers to compare, whatever they score."""

    name = "brightness"

    def rgb_to_tactile(self, rgb, coverage, hand):
        return (rgb.float().mean((1, 2, 3)) / 255)[:, None, None, None] * coverage


@pytest.fixture(scope="module")
def gate_inputs(tmp_path_factory):
    root = tmp_path_factory.mktemp("gatebeside") / "ds"
    write_synthetic_dataset(root, EPISODES, seed=1)
    commit_split(root, SPLIT_NAME, {"train": ["s0", "s1"], "test": ["s2", "s3"], "ood": [f"h{i}" for i in range(4)]})
    args = argparse.Namespace(dataset=root, gate_frames=64, seed=0, ood_task="held", stress_task="")
    frames = {p: decode_part(root, SPLIT_NAME, p, GateConfig(max_frames=64)) for p in ("test", "ood")}
    return args, frames


class FailingModel(BrightnessModel):
    def rgb_to_tactile(self, rgb, coverage, hand):
        raise RuntimeError("no such layer")


def test_the_gate_scored_beside_is_the_gate_scored_here(gate_inputs):
    args, frames = gate_inputs
    here = GateJob.start(BrightnessModel(), args, frames, beside=False)
    beside = GateJob.start(BrightnessModel(), args, frames, beside=True)
    assert beside.beside and not here.beside
    got, want = beside.result(), here.result()
    assert got == want and len(want[0]) > 0 and "ood" in want[1]
    assert beside.seconds > 0 and here.seconds > 0


def test_a_failure_beside_is_named_and_close_stops_a_running_gate(gate_inputs):
    args, frames = gate_inputs
    with pytest.raises(SystemExit, match="held-out gate, scored beside the evaluation, failed: RuntimeError: no such"):
        GateJob.start(FailingModel(), args, frames, beside=True).result()
    job = GateJob.start(BrightnessModel(), args, frames, beside=True)
    job.close()
    assert not job._process.is_alive() and job._process.exitcode is not None
