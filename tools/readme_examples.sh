#!/usr/bin/env bash
# The README's examples, each run as written, in the current (empty) folder, with the htdata of
# BIN (tools/install_check.sh passes the venv its wheel went into):
#   tools/readme_examples.sh BIN
# "A worked example per command" in order (the sample corpus first, as the README says), the
# publish example to a memory:// URL plus the one line a missing s3fs gives for s3://, and the
# Python example (htdata.open, decoded(0)'s keys; ds.torch names its extra without torch).
# `htdata export lerobot` needs the [export] extra and `htdata view` the [view] one: each runs when
# its package imports, otherwise its one line naming the extra is checked. Exits non-zero at the
# first example that fails.
set -euo pipefail

BIN="$1"
HT="$BIN/htdata"
[ -z "$(ls -A .)" ] || { echo "readme-examples: run me in an empty folder (here: $PWD)"; exit 1; }
ok() { echo "readme-examples: ok: $*"; }
run() { "$@" >"out.log" 2>&1 || { cat out.log; echo "readme-examples: FAILED: $*"; exit 1; }; ok "$*"; }

run "$HT" sample data/raw --quiet
# build
run "$HT" pipelines list
run "$HT" ingest --pipeline opentouch data/raw/opentouch data/dataset
run "$HT" ingest --pipeline touchanything data/raw/touchanything data/dataset
# curate
run "$HT" split data/dataset --ood-task palm_push --name main
run "$HT" rm data/dataset 'ot-home_kitchen_*' --dry-run
# inspect
run "$HT" log data/dataset
run "$HT" diff data/dataset v1 v2
run "$HT" stats data/dataset --brief
run "$HT" validate data/dataset --split main
if grep -q "split_ratio_far" out.log; then cat out.log; echo "readme-examples: FAILED: validate warns about the split's own defaults"; exit 1; fi
run "$HT" preview data/dataset preview.png
if "$BIN/python" -c "import rerun" 2>/dev/null; then
  run "$HT" view data/dataset --save ep.rrd
else
  if "$HT" view data/dataset --save ep.rrd 2>view.err; then
    echo "readme-examples: FAILED: view without rerun-sdk exited 0"; exit 1
  fi
  [ "$(wc -l <view.err)" -eq 1 ] && grep -q "pip install '.\[view\]'" view.err \
    || { cat view.err; echo "readme-examples: FAILED: view without rerun-sdk is not one line naming '.[view]'"; exit 1; }
  ok "htdata view without rerun-sdk: $(cat view.err)"
fi
run "$HT" card data/dataset card.html --title "My gloves" --license CC-BY-4.0
# share
if "$BIN/python" -c "import pyarrow" 2>/dev/null; then
  run "$HT" export lerobot data/dataset data/lerobot
else
  if "$HT" export lerobot data/dataset data/lerobot 2>export.err; then
    echo "readme-examples: FAILED: export lerobot without pyarrow exited 0"; exit 1
  fi
  grep -q "\[export\]" export.err || { cat export.err; echo "readme-examples: FAILED: no hint naming [export]"; exit 1; }
  ok "htdata export lerobot without pyarrow names the [export] extra"
fi
"$BIN/python" - <<'EOF'
# the publish example, to a memory:// URL (same process: memory:// lives in it), read back
import sys
from htdata.cli import main
import htdata
assert main(["publish", "data/dataset", "memory://bucket/my-dataset", "--quiet"]) == 0
far, near = htdata.open("memory://bucket/my-dataset"), htdata.open("data/dataset")
assert len(far) == len(near) and far.sample(0) == near.sample(0)
print("readme-examples: ok: htdata publish data/dataset memory://bucket/my-dataset (read back)")
EOF
if "$BIN/python" -c "import s3fs" 2>/dev/null; then
  ok "s3fs is installed here: the missing-backend line is checked by tests/store/test_remote.py"
else
  if "$HT" publish data/dataset s3://bucket/my-dataset 2>s3.err; then echo "readme-examples: FAILED: s3:// without s3fs exited 0"; exit 1; fi
  [ "$(wc -l <s3.err)" -eq 1 ] && grep -q "pip install s3fs" s3.err \
    || { cat s3.err; echo "readme-examples: FAILED: s3:// without s3fs is not one line naming s3fs"; exit 1; }
  ok "htdata publish data/dataset s3://bucket/my-dataset without s3fs: $(cat s3.err)"
fi
"$BIN/python" - <<'EOF'
# the Python example
import htdata
ds = htdata.open("data/dataset")
sample = ds.decoded(0)
assert set(sample) == {"rgb", "tactile", "bend", "raw", "meta"}, sorted(sample)
assert sample["rgb"].shape == (224, 224, 3) and all(m.shape == (224, 224) for m in sample["tactile"].values())
try:
    import torch  # noqa: F401
except ImportError:
    try:
        ds.torch.frames(split="main", part="train")
    except ModuleNotFoundError as exc:
        assert "htdata[torch]" in str(exc), exc
    else:
        raise AssertionError("ds.torch worked without torch")
else:
    train = ds.torch.frames(split="main", part="train")
    clips = ds.torch.windows(window=3, split="main", part="train")
    assert len(train) and len(clips)
print("readme-examples: ok: the Python example (htdata.open, decoded(0), ds.torch)")
EOF
echo "readme-examples: all README examples ran"
