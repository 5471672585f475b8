#!/usr/bin/env bash
# `make install-check`: prove a real (non-editable) install works, as a new user
# would use it. Builds the sdist and the wheel from it (python -m build),
# installs the wheel into a fresh venv under a temp dir, then, from a directory
# outside the checkout and with HTDATA_ROOT unset, runs
#   htdata layouts -> sample (tiny) -> ingest (shipped pipelines by name) -> split -> validate --deep
# with the data core alone (no extras: torch must not come in), and checks that the torch datasets
# then name the extra to install and that `htdata bench --help` works (a run names [bench]); then runs every README example as written from an empty folder
# (tools/readme_examples.sh: the publish example to memory://, s3:// without s3fs is one line),
# and the export example again once the [export] extra is installed.
# and checks that schemas/pipelines/configs resolve inside the installed package and
# that the entry point of HandTouch's bench section is registered.
# KEEP=1 keeps the temp dir; PYTHON picks the interpreter (default python3).
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
PYTHON="${PYTHON:-python3}"
TMP="$(mktemp -d "${TMPDIR:-/tmp}/htdata-install-check.XXXXXX")"
if [ "${KEEP:-0}" = "1" ]; then echo "install-check: keeping $TMP"; else trap 'rm -rf "$TMP"' EXIT; fi
unset HTDATA_ROOT PYTHONPATH
step() { echo "install-check [$(( SECONDS ))s]: $*"; }
# Quiet unless it fails: pip's index warnings go to a log shown on error.
logged() { local log="$TMP/$1.log"; shift; "$@" >"$log" 2>&1 || { cat "$log"; echo "install-check: FAILED: $*"; exit 1; }; }

step "fresh venv $TMP/venv"
"$PYTHON" -m venv "$TMP/venv"
BIN="$TMP/venv/bin"
logged pip-build "$BIN/python" -m pip install build

step "build sdist + wheel (the wheel is built from the sdist)"
logged build "$BIN/python" -m build --outdir "$TMP/dist" "$ROOT"
WHEEL="$(ls "$TMP"/dist/*.whl)"

step "pip install $(basename "$WHEEL") (the data core: no extras, so no torch)"
logged pip-install "$BIN/python" -m pip install "$WHEEL"
if "$BIN/python" -c "import torch" 2>/dev/null; then
  echo "install-check: FAILED: the data core pulled in torch (it belongs to the [torch]/[train]/[bench] extras)"; exit 1
fi

mkdir "$TMP/work"
cd "$TMP/work"          # outside the checkout: nothing may be read from $ROOT

step "data folders resolve inside the installed package"
"$BIN/python" - "$ROOT" <<'EOF'
import sys
from pathlib import Path

import htdata
from htdata import resources
from handtouch.resources import config_file

root = Path(sys.argv[1]).resolve()
package = Path(htdata.__file__).resolve().parent
assert root not in package.parents, f"htdata imported from the checkout: {package}"
for path in (resources.SCHEMAS_DIR, resources.LAYOUTS_DIR, resources.PIPELINES_DIR, config_file("smoke")):
    assert package.parent in Path(path).resolve().parents, f"{path} is not inside the installed package"
    print("  ", path)
from importlib import metadata   # (not htdata.benchmarks: the bench needs the [bench] extra)
sections = {ep.name: ep for ep in metadata.entry_points(group="htdata.bench_sections")}
assert "training" in sections, f"HandTouch's bench section is not registered: {sorted(sections)}"
print("   bench sections:", ", ".join(f"{n} = {ep.value}" for n, ep in sections.items()))
EOF

step "htdata layouts"
"$BIN/htdata" layouts >"$TMP/layouts.txt"
grep -q opentouch_right_16x16 "$TMP/layouts.txt" || { cat "$TMP/layouts.txt"; echo "layouts missing"; exit 1; }

step "htdata sample (tiny)"
"$BIN/htdata" sample raw --scale tiny --seed 0 --quiet >/dev/null

step "htdata ingest (shipped pipelines by name)"
"$BIN/htdata" ingest --workers 2 --quiet \
  --pipeline opentouch=raw/opentouch --pipeline touchanything=raw/touchanything --pipeline native=raw/native \
  dataset

step "htdata split"
"$BIN/htdata" split dataset --ood-task power_grasp --seed 0 --name main >/dev/null

step "htdata validate --deep"
logged validate "$BIN/htdata" validate dataset --split main --deep

step "the torch datasets without torch name the extra to install"
if "$BIN/python" -c "import htdata.read.torchdata" 2>"$TMP/torch.err"; then
  echo "install-check: FAILED: htdata.read.torchdata imported without torch"; exit 1
fi
grep -q "htdata\[torch\]" "$TMP/torch.err" || { cat "$TMP/torch.err"; echo "install-check: FAILED: no hint"; exit 1; }

step "htdata bench without torch: --help teaches, a run is one line naming the [bench] extra"
"$BIN/htdata" bench --help >/dev/null || { echo "install-check: FAILED: htdata bench --help without torch"; exit 1; }
if "$BIN/htdata" bench --quick --out "$TMP/bench" 2>"$TMP/bench.err"; then
  echo "install-check: FAILED: htdata bench ran without torch"; exit 1
fi
grep -q "htdata\[bench\]" "$TMP/bench.err" || { cat "$TMP/bench.err"; echo "install-check: FAILED: no hint"; exit 1; }

step "the README's examples, each as written, from an empty folder (tools/readme_examples.sh)"
mkdir "$TMP/readme"
( cd "$TMP/readme" && HTDATA_CACHE="$TMP/cache" "$ROOT/tools/readme_examples.sh" "$BIN" )

step "pip install the wheel's [export] extra (pyarrow), then the README's export example"
logged pip-export "$BIN/python" -m pip install "$WHEEL[export]"
( cd "$TMP/readme" && "$BIN/htdata" export lerobot data/dataset data/lerobot >/dev/null 2>&1 ) \
  || { echo "install-check: FAILED: htdata export lerobot data/dataset data/lerobot with [export]"; exit 1; }

step "ok"
