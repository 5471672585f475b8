"""The real raw-count glove's facts, measured on the sample raw-count glove and (given) on real recordings.

    .venv/bin/python tools/rawglove_facts.py [--real FOLDER] [--seed N] [--json FILE]

Measures both with htdata/synthetic/rawfacts.py (one measure for both) and prints
- the facts (rawfacts.FACTS): each pooled number of the sample glove (and of the
  real clips) beside the range the real glove's description states;
- the comparison (rawfacts.COMPARED): min / median / max over (clip, hand) of
  each measure, real beside sample;
- how well "pressed" measured from the sample glove's counts matches its truth.
FOLDER holds clips/*.npz (key "counts", (T, 2, 32, 32), hand 0 = left) and
layouts/*.json, e.g. ../shared/real_glove. Exit 1 when a sample-glove fact is
out of its range.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from htdata.synthetic.rawfacts import FACTS, comparison, corpus_facts, fact_failures, folder_rows, sample_rows


def _num(v) -> str:
    return "-" if v is None else f"{v:.3g}" if isinstance(v, float) else str(v)


def _trio(t) -> str:
    return "-" if t is None else f"{t[0]:.3g} / **{t[1]:.3g}** / {t[2]:.3g}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--real", type=Path, help="a folder of real clips (clips/*.npz + layouts/*.json)")
    ap.add_argument("--seed", type=int, default=0, help="the sample glove's seed (default 0, as `htdata sample`)")
    ap.add_argument("--json", type=Path, help="also write the numbers here")
    args = ap.parse_args(argv)
    sample, truth = sample_rows(args.seed)
    real = folder_rows(args.real) if args.real else []
    pooled = {"sample": corpus_facts(sample), "real": corpus_facts(real) if real else {}}
    frames = lambda rows: f"{len({r['clip'] for r in rows})} clips, {min(r['frames'] for r in rows)}-" \
                          f"{max(r['frames'] for r in rows)} frames"   # noqa: E731
    print(f"sample glove (seed {args.seed}): {frames(sample)}" + (f"; real ({args.real}): {frames(real)}" if real else ""))
    print("\n| fact | range | real | sample |\n|---|---|---|---|")
    for f in FACTS:
        print(f"| {f.says} | {f.low:g} .. {f.high:g} | {_num(pooled['real'].get(f.key))} | "
              f"{_num(pooled['sample'][f.key])} |")
    rows = comparison(real, sample) if real else comparison(sample, sample)
    print("\nmin / **median** / max over (clip, hand)\n\n| measure | real | sample |\n|---|---|---|")
    for r in rows:
        print(f"| {r['measure']} | {_trio(r['real']) if real else '-'} | {_trio(r['sample'])} |")
    print("\nsample glove, working hand: pressed measured from the counts (rise over the cell's p10 > 15) against "
          "the generator's truth\n\n| clip | precision | recall |\n|---|---|---|")
    for t in truth:
        print(f"| {t['clip']} | {t['precision']:.2f} | {t['recall']:.2f} |")
    bad = fact_failures(pooled["sample"])
    for line in bad:
        print(f"sample glove: {line}", file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps({"pooled": pooled, "comparison": rows, "truth": truth}, indent=1))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
