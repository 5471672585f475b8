# htdata + HandTouch. Every target installs what it needs first (make setup).
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
HTDATA := $(VENV)/bin/htdata
DATA   ?= data
SEED   ?= 0
OOD    ?= palm_push
JOBS   ?= 2

.PHONY: setup demo sample ingest split validate preview train-smoke compare task-transfer test install-check bench clean

setup: $(VENV)/.installed

# Everything: the data core plus the torch datasets, the trainer, the bench, Ray and the tests
# (torch==2.13.0 is pinned in pyproject.toml: the CPU wheel on the machine's disk).
$(VENV)/.installed: pyproject.toml setup.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[torch,train,bench,ray,test]"
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
	$(HTDATA) split $(DATA)/dataset --ood-task $(OOD) --seed $(SEED) --name main --force

validate: split
	$(HTDATA) validate $(DATA)/dataset --split main --deep

preview: validate
	$(HTDATA) preview $(DATA)/dataset $(DATA)/preview.png

# Trains the three HandTouch stages + baselines on the sample data, scores HT-Bench.
train-smoke: setup
	$(PY) -m handtouch.smoke --out runs/smoke --raw $(DATA)/raw --dataset $(DATA)/dataset

# HandTouch vs the 4 encoder baselines, 3 ablations and 3 design rows, same data / split / budget.
compare: setup
	$(PY) -m handtouch.compare --config configs/compare_smoke.toml --out runs/compare --raw $(DATA)/raw \
	  --dataset $(DATA)/dataset --rgb-cache runs/smoke/rgb_encoder

# For each task: an RGB probe trained on the other tasks, scored on it (does RGB transfer to new
# tasks?), and the smoke's misalignment controls on each such split (~4 min).
task-transfer: ingest
	$(PY) -m handtouch.task_transfer --dataset $(DATA)/dataset --out runs/task_transfer --controls

demo: preview train-smoke
	@echo "demo done: $(DATA)/dataset, $(DATA)/preview.png, runs/smoke/results.md"

test: setup
	$(PY) -m pytest -q -n $(JOBS) --dist loadfile

# A real install: build sdist + wheel, install the wheel into a fresh venv under a
# temp dir, run layouts -> sample -> ingest -> split -> validate outside the checkout.
install-check:
	PYTHON=$(PYTHON) tools/install_check.sh

bench: setup
	$(HTDATA) bench --out bench

clean:
	rm -rf $(DATA) runs bench/.work
