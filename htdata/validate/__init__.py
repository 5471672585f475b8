"""`htdata validate`: prove a committed dataset is sound.

Checks (each a named section of the report, with counts and every failure
pinpointed by shard / sample key / episode / frame / expected / found), one
module each:

- structure (`loaded.py` reads the version, `structure.py` checks it): dataset.json,
  the episode records and every sample JSON valid against schemas/; the sha256 of
  every record file (format 4: each segment's, and the records they give against the
  manifest's episodes_sha256 / index_sha256; format 3: episodes.jsonl, index.npy); every
  listed shard present with its sha256 and size, no extra shard; sample
  counts per shard and per episode; unique keys; each episode's frames
  contiguous and ordered 0..n-1; the tar header at every index offset names
  `key.suffix` with the indexed size (one 512-byte read per member: cheap
  for all samples).
- content (`content.py`): decodes every sample (`--deep`) or a seeded sample
  (`--sample-frac`, plus the first frame of every episode): RGB (224,224,3)
  uint8; tactile EXR (224,224; half or float, as the codec records), finite, in [0,1], zero outside the
  layout's coverage; bend vectors 1-D finite.
- served maps (`served.py`, part of content): for each episode's first
  decoded sample and a seeded tenth of the others, each map as the torch
  datasets serve it (rendered from the raw rows under the
  recorded calibration, their default) equals the stored map within the
  stored pixel type's rounding: one truth for what a map is.
- calibration records (`calibrations.py`; structure, and content with --deep):
  every calibration id recomputed from its settings, every episode's
  `calibration_fit` against its digest (a reader refuses such a version too);
  with --deep every episode hand's taxels re-derived from the raw rows
  against the ingest's `taxels_sha256`.
- time (`timestamps.py`): RGB timestamps strictly increasing per episode;
  tactile timestamps never decrease (a repeated tactile timestamp means one
  glove frame was paired with two RGB frames, which nearest-neighbour sync
  allows when the glove is slower than the camera: counted as a warning);
  gaps (> 1.5 periods) and fps deviation (> 5%) warn; |t_rgb - t_tactile|
  above the sync tolerance (episode sync report `max_skew_ns`, else the
  source pipeline's `sync.max_skew_ms`) fails.
- sensors (`sensors.py`, warnings only): regions (canonical region map within
  coverage) whose mean never changes over an episode's decoded frames (dead
  if always 0, stuck otherwise), saturated fraction (>= 0.999), all-zero hands.
- splits (`splits.py`, `--split NAME`): the split's manifest hash; OOD tasks
  absent from train and test; parts disjoint and covering every episode; no
  byte-identical frame (sha256 of rgb + tactile member bytes) in two parts;
  stated counts and ratios equal to what the parts hold. `check_split_records`
  runs the ones that read no sample (no frame hashing): the smoke's leak check.
- stats (`stats.py`): frames per task / scene / hand; contact-area and
  pressure histograms.

Shards are checked by workers (`shards.py`: one task per shard, a process
pool when workers > 1): the main process only merges small per-shard
results. `validator.validate_dataset` runs it all and returns the report
(`report.py`: Check objects, text form).
Shared by the checks: `geometry.py` (per-layout covered pixels and their
regions), `samplejson.py` (one sample's JSON against its schema, index row
and members); `validator.py` holds `validate_dataset`; `gate.py` runs it as a
gate (`require_valid`: `htdata publish` refuses a version that fails, naming
the first failing check). Exit status of the command: 0 when every check
passes (warnings allowed), 1 otherwise.

May import: reading, inspection (the stats cache), the store, the glove model, the format and the
base modules. Never the writers (write, ingest, curate: validate writes no version), the
benchmarks or the commands.
"""

from htdata.validate.report import CHECKS, Check, format_report, write_report
from htdata.validate.splits import check_split_records
from htdata.validate.structure import group_rows
from htdata.validate.validator import ValidateConfig, validate_dataset

__all__ = ["CHECKS", "Check", "ValidateConfig", "check_split_records", "format_report", "group_rows",
           "validate_dataset", "write_report"]
