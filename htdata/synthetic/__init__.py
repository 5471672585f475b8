"""Synthetic raw corpus in the three source formats (`htdata sample`, htdata/commands/sample.py).

- `tasks`: task profiles, canonical place names, scene styles, stable hashes;
- `world`: one episode's hidden state (hand trajectory, grip force, closure) over time;
- `hand`: hand geometry (joint positions, where the hand meets the object);
- `glove`: paints a glove layout's contact grids from a hand state;
- `render`: draws the egocentric RGB frames (backdrop, object, hands);
- `formats`: writers of each source layout (OpenTouch-style HDF5,
  TouchAnything-style folders, htdata-native folders);
- `corpus`: plans the episodes of a corpus and writes them through `formats`;
- `controls`: broken control corpora (RGB of another episode, behind the glove, played backwards);
- `state`: the hidden state of one hand over time (what the glove painter and the renderer read);
- `rawglove`: a raw-count knit glove (two hands, 32x32, float16 counts) with the ground truth behind it;
  `rawlayout` its wiring and layouts, `rawgrip` its grips, `restwander` the slow wander of its cells at rest;
- `rawfacts`: the facts of a raw-count glove measured from its counts (the sample glove, or real
  recordings the caller names).

May import: sources (the formats it writes, the adapters' registry), the glove model, the format
and the base modules. Never the store, reading, the writers, validate, the benchmarks or the commands:
it writes recordings, not datasets.
"""
