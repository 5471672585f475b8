"""What a new user trips over: --help that teaches, pipeline names, `v3` versions, stats --brief."""

from __future__ import annotations

import re

import pytest

from htdata.cli import COMMANDS, GROUPS
from htdata.cli import main as cli
from htdata.commands.version_arg import parse_version
from htdata.ingest.pipeline import load_pipeline, resolve_pipeline_path, shipped_pipelines
from tests.factories import SPLIT_EPISODES, commit_split, write_synthetic_dataset
from tests.factories.tactile import LEFT, RIGHT, clean_series, write_taxel_dataset

# Names of our modules and functions that once leaked into --help: a user has no use for them.
INTERNAL = re.compile(r"plan_edit|repack\.py|frames_from_raw|structure\.py|\w+\.py\b|EXR half")


def help_text(capsys, *argv) -> str:
    with pytest.raises(SystemExit) as exit_info:
        cli([*argv, "--help"])
    assert exit_info.value.code == 0
    return capsys.readouterr().out


def test_top_level_help_groups_every_command(capsys):
    grouped = [c for names in GROUPS.values() for c in names]
    assert sorted(grouped) == sorted(COMMANDS) and len(grouped) == len(set(grouped))
    text = help_text(capsys)
    for group in ("build:", "curate:", "inspect:", "share:"):
        assert f"\n{group}\n" in text
    assert text.index("build:") < text.index("  ingest ") < text.index("curate:") < text.index("  trim ")
    assert text.index("share:") < text.index("  export ")


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_command_help_ends_with_real_examples(capsys, command):
    argv = ["export", "lerobot"] if command == "export" else [command]
    text = help_text(capsys, *argv)
    tail = text.rstrip().split("\n")
    at = max(i for i, line in enumerate(tail) if line.strip().lower().startswith("examples"))
    examples = [line for line in tail[at + 1:] if line.strip().startswith(f"htdata {command}")]
    assert examples, f"htdata {command} --help: no example after 'Examples:'"
    assert all(line.startswith("  ") or not line.strip() or line.startswith("Open") for line in tail[at + 1:])
    assert not INTERNAL.search(text), INTERNAL.search(text).group(0)
    # every option with a default says what it is
    import argparse
    import importlib

    parser = argparse.ArgumentParser()
    importlib.import_module(COMMANDS[command][0]).configure_parser(parser)
    if command == "export":
        parser = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices["lerobot"]
    for action in parser._actions:
        if action.option_strings and action.default not in (None, False, [], argparse.SUPPRESS) and action.help:
            assert "default" in action.help.lower(), f"htdata {command} {action.option_strings[0]}: default unstated"


def test_versions_are_accepted_as_printed(tmp_path, capsys):
    assert parse_version("v3") == parse_version("3") == parse_version(" V3 ") == 3
    with pytest.raises(ValueError, match="write 3 or v3"):
        parse_version("three")
    root = write_synthetic_dataset(tmp_path / "ds", SPLIT_EPISODES)
    commit_split(root, "main", {"train": ["ep_a"], "test": ["ep_b"]})
    assert cli(["diff", str(root), "v1", "v2"]) == 0
    assert "v1 -> v2" in capsys.readouterr().out
    assert cli(["diff", str(root), "1", "2"]) == 0
    with pytest.raises(SystemExit) as exit_info:
        cli(["diff", str(root), "v1", "latest"])
    assert exit_info.value.code == 2 and "not a version: 'latest'" in capsys.readouterr().err


def test_a_directory_is_never_a_pipeline_file(tmp_path, monkeypatch):
    (tmp_path / "opentouch").mkdir()                    # the raw data folder, named like the pipeline
    monkeypatch.chdir(tmp_path)
    path = resolve_pipeline_path("opentouch")
    assert path.is_file() and path.suffix == ".toml"
    assert load_pipeline("opentouch").name == "opentouch"


def test_unknown_pipeline_lists_the_shipped_names(capsys):
    assert shipped_pipelines() == ["native", "opentouch", "touchanything"]
    with pytest.raises(FileNotFoundError, match="native, opentouch, touchanything"):
        load_pipeline("opentuch")
    assert cli(["pipelines", "list"]) == 0
    out = capsys.readouterr().out
    assert all(re.search(rf"^{name}\s", out, re.M) for name in shipped_pipelines())
    assert cli(["pipelines", "show", "native"]) == 0
    assert '[adapter]\nname = "native"' in capsys.readouterr().out
    assert cli(["pipelines", "show", "nope"]) == 2
    assert "shipped: native, opentouch, touchanything" in capsys.readouterr().err


def test_stats_brief_is_a_short_summary_first(tmp_path, capsys):
    root = write_taxel_dataset(tmp_path / "ds", [
        {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": {"right": (RIGHT, clean_series(RIGHT, 12, 1))}},
        {"episode_id": "ep_b", "task": "wipe", "scene": "office",
         "hands": {"right": (RIGHT, clean_series(RIGHT, 10, 2)), "left": (LEFT, clean_series(LEFT, 10, 3))}}])
    assert cli(["stats", str(root), "--brief"]) == 0
    brief = capsys.readouterr().out.strip().split("\n")
    assert len(brief) == 4 and "2 episodes" in brief[0] and "2 tasks" in brief[0]
    assert "contact in" in brief[2] and "flagged" in brief[2]
    assert brief[1].startswith("contact = a frame with any taxel > 0.02")     # the rule these gloves use
    assert cli(["stats", str(root)]) == 0
    full = capsys.readouterr().out.strip().split("\n")
    assert full[:len(brief)] == brief and len(full) > len(brief) + 5


def test_rm_help_promises_only_the_suggestions_it_gives(tmp_path, capsys):
    """The miss names the pattern and the episode count; 'did you mean' only where ids are spelled alike."""
    assert "with the ids spelled like it when there are any" in help_text(capsys, "rm")
    root = write_synthetic_dataset(tmp_path / "ds", SPLIT_EPISODES[:4])
    ids = [e["episode_id"] for e in SPLIT_EPISODES[:4]]
    assert cli(["rm", str(root), ids[0] + "x"]) == 2
    err = capsys.readouterr().err
    assert f"no episode matches {ids[0] + 'x'!r} (4 episodes); did you mean: {ids[0]}" in err
    assert cli(["rm", str(root), "zzz-*"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("no episode matches 'zzz-*' (4 episodes)") and "did you mean" not in err


def test_bench_help_works_without_torch_and_a_run_names_the_extra(tmp_path):
    """An install without the [bench] extra: `htdata bench --help` teaches; a run is one line naming the extra."""
    import subprocess
    import sys
    from pathlib import Path

    from tests.factories.notorch import without_torch

    env = without_torch(tmp_path / "notorch", Path(__file__).resolve().parents[2])
    probe = subprocess.run([sys.executable, "-c", "import torch"], env=env, capture_output=True, text=True)
    assert probe.returncode != 0 and "No module named 'torch'" in probe.stderr     # the blocker works
    helped = subprocess.run([sys.executable, "-m", "htdata.cli", "bench", "--help"], env=env, capture_output=True,
                            text=True)
    assert helped.returncode == 0 and "Examples:" in helped.stdout and "Traceback" not in helped.stderr
    ran = subprocess.run([sys.executable, "-m", "htdata.cli", "bench", "--quick", "--out", str(tmp_path / "b")],
                         env=env, capture_output=True, text=True)
    assert ran.returncode == 2 and ran.stderr.strip().splitlines() == [
        "htdata bench: error: htdata bench needs torch (its loader sections time the torch datasets): "
        "pip install 'htdata[bench]'"]
    assert not (tmp_path / "b").exists()
