# htdata + HandTouch. Every target installs what it needs first (make setup).
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
HTDATA := $(VENV)/bin/htdata
DATA   ?= data
SEED   ?= 0
# held out whole by `make split`: the smoke's held-out task (power_grasp's touch on a new object) and
# its stress test (palm-only touch, no training twin); docs/HANDTOUCH.md "Held-out gate"
OOD    ?= cup_grasp palm_push
JOBS   ?= 2

.PHONY: setup demo demo-intro sample ingest split validate preview train-smoke train-smoke-mispaired train-smoke-lagged train-smoke-reversed compare task-transfer test lint fix install-check bench \
        ray-cluster-check \
        lerobot-check lerobot-load export-lerobot gpu-check clean

setup: $(VENV)/.installed

# Everything: the data core plus the torch datasets, the trainer, the bench, Ray, the Rerun viewer and the tests
# (torch==2.13.0 is pinned in pyproject.toml: the CPU wheel on the machine's disk).
$(VENV)/.installed: pyproject.toml setup.py
	$(PYTHON) -m venv $(VENV)
	@echo "make setup: installing htdata with every extra into $(VENV)/ (about 2 GB; 2-3 min the first time)"
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install --progress-bar off -e ".[torch,train,bench,export,ray,test,view]"   # a line per package: progress
	touch $@

# Raw sample corpus: written once, reused after (--reuse: a finished corpus of this seed, which
# the smoke writes too, is kept; one cut short is written again).
sample: setup
	$(HTDATA) sample $(DATA)/raw --seed $(SEED) --scale small --reuse

# Re-running resumes: finished work units are skipped by checksum.
ingest: sample
	$(HTDATA) ingest --workers $(JOBS) \
	  --pipeline pipelines/opentouch.toml=$(DATA)/raw/opentouch \
	  --pipeline pipelines/touchanything.toml=$(DATA)/raw/touchanything \
	  --pipeline pipelines/native.toml=$(DATA)/raw/native \
	  $(DATA)/dataset

split: ingest
	$(HTDATA) split $(DATA)/dataset $(addprefix --ood-task ,$(OOD)) --seed $(SEED) --name main --force

validate: split
	$(HTDATA) validate $(DATA)/dataset --split main --deep

preview: validate
	$(HTDATA) preview $(DATA)/dataset $(DATA)/preview.png

# Trains the three HandTouch stages + baselines on the sample data, scores HT-Bench.
train-smoke: setup
	$(PY) -m handtouch.smoke --out runs/smoke --raw $(DATA)/raw --dataset $(DATA)/dataset

# The held-out gate's proof: the smoke on a corpus whose every video shows another episode (htdata
# sample --mispair-rgb, built under runs/smoke_mispaired); exits 0 only if the gate FAILS there.
train-smoke-mispaired: setup
	$(PY) -m handtouch.smoke --out runs/smoke_mispaired --broken mispaired

# The lag check's proof: every video 6 frames (0.2 s) behind its glove (htdata sample --rgb-lag-frames 6,
# under runs/smoke_lagged); exits 0 only if the lag check FAILS there, naming the lag.
train-smoke-lagged: setup
	$(PY) -m handtouch.smoke --out runs/smoke_lagged --broken lagged

# Video played backwards within each episode (htdata sample --reverse-rgb): the held-out gate must fail.
train-smoke-reversed: setup
	$(PY) -m handtouch.smoke --out runs/smoke_reversed --broken reversed

# HandTouch vs the 4 encoder baselines, 3 ablations and 3 design rows, same data / split / budget.
compare: setup
	$(PY) -m handtouch.compare --config configs/compare_smoke.toml --out runs/compare --raw $(DATA)/raw \
	  --dataset $(DATA)/dataset --rgb-cache runs/smoke/rgb_encoder

# For each task: an RGB probe trained on the other tasks, scored on it (does RGB transfer to new
# tasks?), and the smoke's misalignment controls on each such split (~4 min).
task-transfer: ingest
	$(PY) -m handtouch.task_transfer --dataset $(DATA)/dataset --out runs/task_transfer --controls

# Printed first, so the wait is known up front (measured on an idle 2-core machine; a busy one takes longer).
demo-intro:
	@echo "make demo: install (2-3 min the first time), sample recordings + ingest + split + validate + preview"
	@echo "  (~1 min), then the HandTouch smoke (~3-4 min): about 7 min on an idle 2-core machine, more when it is busy"

demo: demo-intro preview train-smoke
	@echo "demo done: $(DATA)/dataset, $(DATA)/preview.png, runs/smoke/results.md"

# Lint: ruff's error rules and import order (pyproject.toml [tool.ruff]); `make fix` applies its fixes.
lint: setup
	$(VENV)/bin/ruff check htdata handtouch tests tools setup.py

fix: setup
	$(VENV)/bin/ruff check --fix htdata handtouch tests tools setup.py

test: setup
	$(PY) -m pytest -q -n $(JOBS) --dist loadfile

# Ingest on a real two-node Ray cluster (`ray start --head` + `ray start --address`, separate processes
# and temp dirs) writes the process pool's dataset byte for byte; both nodes are stopped by process id,
# even on failure. Not in `make test` (two Ray nodes: ~1 GB, ~1 min on 2 cores); CI runs it.
ray-cluster-check: setup
	$(PY) -m pytest -q -m cluster tests/ingest/test_ray_cluster.py

# A real install: build sdist + wheel, install the wheel into a fresh venv under a
# temp dir, run layouts -> sample -> ingest -> split -> validate outside the checkout.
install-check:
	PYTHON=$(PYTHON) tools/install_check.sh

# The real-glove section measures the raw-count rules on ../shared/real_glove when that folder exists
# (REAL_GLOVE= to leave it out; without it the section says it was not measured).
REAL_GLOVE ?= $(wildcard ../shared/real_glove)
bench: setup
	$(HTDATA) bench --out bench $(if $(REAL_GLOVE),--real-glove $(REAL_GLOVE))

# HandTouch stage 1 (configs/full.toml, bf16) on a CUDA GPU at batch 32 / 8 workers and 128 / 16:
# samples/s, data-wait share, GPU busy share. No `setup`: it runs on a machine that already has
# torch (a CUDA build) and the dependencies of pyproject.toml, with the checkout on PYTHONPATH
# (GPU_PY: the project's venv python when it exists, so `make gpu-check` after `make demo` finds its
# torch; python3 otherwise). Builds the medium sample dataset under GPU_WORK first (reused after),
# unless GPU_CHECK_ARGS="--dataset DIR". JSON: $$OUT/gpucheck.json if OUT is set.
# Exits 2 without a GPU, 3 with a dependency missing (named).
GPU_PY         ?= $(if $(wildcard $(PY)),$(PY),python3)
GPU_WORK       ?= /tmp/ht_gpucheck
GPU_CHECK_ARGS ?= --compile --profile 20
gpu-check:
	PYTHONPATH=$(CURDIR)$${PYTHONPATH:+:$$PYTHONPATH} $(GPU_PY) -m handtouch.gpucheck --work $(GPU_WORK) $(GPU_CHECK_ARGS)

# LeRobot v3.0 export of the sample dataset (pyarrow comes with make setup's [export] extra), with the
# glove at its own rate: up to LEROBOT_WINDOW rows since the previous frame (the sample's 100 Hz glove
# beside 30 fps video stores at most 8 in a frame; more is an error naming the K needed).
LEROBOT_WINDOW ?= 8
export-lerobot: split
	$(HTDATA) export lerobot $(DATA)/dataset $(DATA)/lerobot --split main --force --quiet --tactile-window $(LEROBOT_WINDOW)

# The export checked by LeRobot's own tooling, in a venv of its own (LeRobot's pins differ from
# ours): lerobot-doctor (no torch) must report no FAIL but "Training Readiness" (it FAILs any
# dataset without an `action` feature; htdata records observations only), then
# tools/lerobot_check.py reads the export with pyarrow + PyAV as LeRobot v3.0 documents it and
# compares it with htdata's reader. Both write their full reports to files (the doctor prints a
# line per flagged taxel dimension, ~1,500 on the sample); tools/lerobot_summary.py prints one
# line per doctor check, the rows compared and the RGB difference, names the files and gives
# the verdict (the exit status). LeRobot's loader itself: `make lerobot-load` (below, not in CI).
LEROBOT_VENV ?= .venv-lerobot
LEROBOT_REPORTS := $(DATA)/lerobot_doctor.md $(DATA)/lerobot_doctor.txt $(DATA)/lerobot_check.json $(DATA)/lerobot_check.txt

$(LEROBOT_VENV)/.installed:
	$(PYTHON) -m venv $(LEROBOT_VENV)
	$(LEROBOT_VENV)/bin/python -m pip install -q "lerobot-doctor==0.2.0"
	touch $@

lerobot-check: export-lerobot $(LEROBOT_VENV)/.installed
	@rm -f $(LEROBOT_REPORTS)
	@$(LEROBOT_VENV)/bin/lerobot-doctor check $(DATA)/lerobot --markdown $(DATA)/lerobot_doctor.md \
	  > $(DATA)/lerobot_doctor.txt 2>&1; \
	$(PY) tools/lerobot_check.py $(DATA)/dataset $(DATA)/lerobot --json $(DATA)/lerobot_check.json \
	  > $(DATA)/lerobot_check.txt 2>&1; \
	$(PY) tools/lerobot_summary.py $(DATA)/lerobot_doctor.md $(DATA)/lerobot_check.json \
	  --expected-fail "Training Readiness=no action feature: htdata records observations only" \
	  --expected-fail-messages "Action Quality=^observation\.tactile\.\w+\.window\w*\[\d+\]: .* -- clipping detected$$=only the tactile windows' padding slots (0 in most frames), read as clipped actions" \
	  $(foreach f,$(LEROBOT_REPORTS),--full $(f))

# LeRobot's own loader (lerobot-dataset's LeRobotDataset) on the export: NOT in CI. Its venv is
# ~6.3 GB (torch 2.14.1 + torchvision 0.29.1, CUDA builds that run on CPU; installed in 1m46s
# here) and its video decoder, torchcodec, needs the system's FFmpeg libraries (Debian: apt-get
# install libavcodec59 libavformat59 libavutil57 libswscale6 libswresample4 libavdevice59 libavfilter8).
LEDATASET_VENV ?= .venv-ledataset

$(LEDATASET_VENV)/.installed:
	$(PYTHON) -m venv $(LEDATASET_VENV)
	$(LEDATASET_VENV)/bin/python -m pip install -q "lerobot-dataset==0.4.4" "torch==2.14.1" "torchvision==0.29.1" "torchcodec==0.14.0"
	touch $@

lerobot-load: export-lerobot $(LEDATASET_VENV)/.installed
	HF_HUB_OFFLINE=1 $(LEDATASET_VENV)/bin/python tools/lerobot_load.py $(DATA)/lerobot --json $(DATA)/lerobot_load.json

clean:
	rm -rf $(DATA) runs bench/.work
