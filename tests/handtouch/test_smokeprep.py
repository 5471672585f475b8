"""The smoke's evaluation inputs built in a spawned process beside training (handtouch.smokeprep):
the same values as built in the smoke's own process, and a child's failure named in the parent."""

import dataclasses

import pytest
import torch

from handtouch.bench.evaluate import evaluate
from handtouch.bench.items import EvalConfig, load_part, prepare
from handtouch.bench.references import CopyLastModel, ZerosModel
from handtouch.contact_gate import GateConfig, decode_part
from handtouch.probeitems import load_items
from handtouch.rgb_pretrain import RGBPretrainConfig, control_scores, ensure_probes
from handtouch.smokeprep import CONTROL_PROBE_THREADS, EvalInputs, InputsRequest
from tests.factories import commit_split, episode_table, write_synthetic_dataset

EPISODES = episode_table(*[(f"ep{i}", "grab", "lab", "R", 10) for i in range(6)],
                         *[(f"h{i}", "held", "lab", "R", 10) for i in range(2)])
TINY = RGBPretrainConfig(steps=4, batch_size=8, threads=1, max_items=64,
                         arch={"size": 16, "width": 16, "channels": 4, "grid": 14, "hidden": 32})


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("smokeprep") / "ds"
    write_synthetic_dataset(root, EPISODES, seed=3, fps=4.0)
    commit_split(root, "s", {"train": [f"ep{i}" for i in range(4)], "test": ["ep4", "ep5"], "ood": ["h0", "h1"]})
    return root


def _numbers(tree, at=""):
    """{path: number} of a nested dict of scores, wall seconds left out (pytest.approx compares flat
    mappings)."""
    if isinstance(tree, dict):
        return {k: v for key, sub in tree.items() for k, v in _numbers(sub, f"{at}/{key}").items()}
    return {at: tree} if isinstance(tree, (int, float)) and "/seconds/" not in at else {}


def _request(root, tmp_path, probes) -> InputsRequest:
    return InputsRequest(root, "s", EvalConfig(max_items=12, seed=1), TINY, GateConfig(max_frames=16, seed=1),
                         probes, tmp_path / "probes", tmp_path / ".inputs.pt")


def test_the_inputs_built_beside_training_are_the_ones_built_in_process(dataset, tmp_path):
    aligned = ensure_probes(dataset, "s", tmp_path / "probes", TINY, pairings=("aligned",))
    got = EvalInputs.start(_request(dataset, tmp_path, aligned)).result()
    assert not (tmp_path / ".inputs.pt").exists()                   # read, then removed from the run folder
    assert set(got.probes) == {"aligned", "shuffled"} and got.probes["aligned"] == aligned["aligned"]
    control = dataclasses.replace(TINY, threads=CONTROL_PROBE_THREADS)
    assert got.probes["shuffled"] == ensure_probes(dataset, "s", tmp_path / "probes", control,
                                                   pairings=("shuffled",))["shuffled"]   # the child cached it

    want = prepare({p: load_part(dataset, "s", p) for p in ("test", "ood")}, cfg=EvalConfig(max_items=12, seed=1))
    for part in ("test", "ood"):
        assert got.prepared[part].items == want[part].items
        for a, b in zip(got.prepared[part].frames, want[part].frames, strict=True):
            assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
        gate = decode_part(dataset, "s", part, GateConfig(max_frames=16, seed=1))
        assert all(torch.equal(got.gate[part][k], gate[k]) for k in gate)
    for model in (ZerosModel(), CopyLastModel()):
        ref = evaluate(model, want)
        assert _numbers(got.references[model.name]) == pytest.approx(_numbers(ref), rel=1e-5, nan_ok=True)
    items = {p: load_items(dataset, "s", p, TINY) for p in ("test", "ood")}
    assert _numbers(got.probe) == pytest.approx(_numbers(control_scores(got.probes, items, TINY)), rel=1e-6)
    assert set(got.seconds) >= {"control_probes", "prepared", "references", "probe", "gate", "since_start"}


def test_a_failure_in_the_child_is_named_in_the_parent(dataset, tmp_path):
    aligned = ensure_probes(dataset, "s", tmp_path / "probes", TINY, pairings=("aligned",))
    req = dataclasses.replace(_request(dataset, tmp_path, aligned), split="no_such_split")
    with pytest.raises(SystemExit, match="beside training failed: .*no_such_split"):
        EvalInputs.start(req).result()
    assert not (tmp_path / ".inputs.pt").exists()


def test_close_stops_a_child_still_building_and_leaves_no_file(dataset, tmp_path):
    aligned = ensure_probes(dataset, "s", tmp_path / "probes", TINY, pairings=("aligned",))
    background = EvalInputs.start(_request(dataset, tmp_path, aligned))
    background.close()                      # at once: the child is still importing or building
    assert not background._process.is_alive() and background._process.exitcode is not None
    assert not (tmp_path / ".inputs.pt").exists() and not (tmp_path / ".inputs.pt.tmp").exists()
