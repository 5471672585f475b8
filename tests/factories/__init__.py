"""Build small, valid, committed datasets from in-memory frames (for tests).

    from tests.factories import write_synthetic_dataset
    root = write_synthetic_dataset(tmp_path / "ds", episodes=[
        {"episode_id": "ep_a", "task": "pour", "scene": "kitchen", "hands": ("right",), "num_frames": 5},
        {"episode_id": "ep_b", "task": "wipe", "scene": "office", "hands": ("left", "right"), "num_frames": 3,
         "layouts": {"left": "glove_l", "right": "glove_r"}},
    ])

Frames are seeded per (seed, episode_id, frame), so `synthetic_members`
regenerates exactly the bytes that were written (tests compare against it).
Everything goes through the real writer APIs (codec, ShardWriter,
commit_dataset). Layout ids default to "test_full" with full-canvas
coverage; pass `coverages={layout_id: (224,224) uint8}` for real ones (e.g.
from htdata.glove.layouts + Rasteriser) and `canonical=CanonicalArtifact(...)`.

Also here: the episode tables the dataset tests share (`episode_table`,
MIXED_HANDS_EPISODES, PREVIEW_EPISODES, SPLIT_EPISODES, TRAIN_EPISODES) and
tiny raw corpora in the three source formats plus the in-process ingest CLI
(`make_opentouch`, `make_two_scene_opentouch`, `make_touchanything`, `make_native`, `small_pipeline`,
`ingest_cli`, `ingest_crashing_at_unit`, `temp_leftovers`) for the ingest, Ray and benchmark tests.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import h5py
import numpy as np

from htdata.format.canvas import CANVAS
from htdata.format.codec import DEFAULT_CODEC_INFO, encode_rgb
from htdata.format.shardio import ShardWriter, sample_key
from htdata.format.table import MANIFEST_FILE
from htdata.format.tactilecodec import encode_tactile
from htdata.resources import PIPELINES_DIR
from htdata.store.manifest import CanonicalArtifact, LayoutArtifact, UnitResult, write_layout_files
from htdata.store.parts import part_from_unit
from htdata.store.snapshot import commit_parts, current_snapshot
from htdata.store.splitfiles import split_path
from htdata.store.versions import version_manifest_file
from htdata.synthetic.formats import (
    NativeHand,
    NativeRecording,
    OpenTouchClip,
    TouchAnythingEpisode,
    write_native_recording,
    write_opentouch_annotations,
    write_opentouch_scene,
    write_touchanything_episode,
)

DEFAULT_LAYOUT = "test_full"
FRAME_NS = 33_333_333


def default_canonical() -> CanonicalArtifact:
    """A small stand-in template: six part bands over a hand-shaped box."""
    part_map = np.zeros((CANVAS, CANVAS), np.uint8)
    # fingers: five columns in the top half (little .. thumb, thumb on the right), palm below
    for part, x0 in zip((5, 4, 3, 2, 1), (20, 60, 100, 140, 180)):
        part_map[10:110, x0:x0 + 30] = part
    part_map[110:214, 20:210] = 6
    region_map = part_map.copy()
    region_map[60:110][part_map[60:110] > 0] += 10  # distal vs proximal places
    doc = {"canvas": CANVAS, "synthetic": True,
           "parts": {"1": "thumb", "2": "index", "3": "middle", "4": "ring", "5": "little", "6": "palm"}}
    return CanonicalArtifact(document=doc, region_map=region_map, part_map=part_map)


def _rng(seed: int, episode_id: str, frame: int, salt: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(episode_id.encode()), frame, salt])


def synthetic_rgb(seed: int, episode_id: str, frame: int) -> np.ndarray:
    """Smooth random colours (JPEG-friendly) + a little noise, (224,224,3) uint8."""
    rng = _rng(seed, episode_id, frame, 0)
    small = rng.integers(0, 256, size=(8, 8, 3), dtype=np.uint8)
    big = cv2.resize(small, (CANVAS, CANVAS), interpolation=cv2.INTER_LINEAR).astype(np.int16)
    big += rng.integers(-6, 7, size=big.shape, dtype=np.int16)
    return np.clip(big, 0, 255).astype(np.uint8)


def synthetic_tactile(seed: int, episode_id: str, frame: int, hand: str, coverage: np.ndarray) -> np.ndarray:
    """Sparse contact: a few Gaussian blobs inside the coverage, peak exactly 1.0 on even frames."""
    rng = _rng(seed, episode_id, frame, 1 if hand == "left" else 2)
    yy, xx = np.mgrid[0:CANVAS, 0:CANVAS].astype(np.float32)
    m = np.zeros((CANVAS, CANVAS), np.float32)
    for _ in range(int(rng.integers(1, 4))):
        cy, cx = rng.uniform(20, 204, size=2)
        sigma = rng.uniform(4, 14)
        m += rng.uniform(0.2, 0.9) * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * sigma ** 2))
    m[m < 0.02] = 0.0  # exact zeros away from contact, like real maps
    m = np.clip(m, 0.0, 1.0) * (coverage > 0)
    if frame % 2 == 0 and m.max() > 0:
        m[np.unravel_index(np.argmax(m), m.shape)] = 1.0
    return m.astype(np.float32)


def synthetic_members(spec: dict, frame: int, seed: int, coverages: dict[str, np.ndarray],
                      bend_dims: int = 0) -> dict[str, bytes]:
    """The tar members of one synthetic sample (deterministic)."""
    eid = spec["episode_id"]
    hands = tuple(spec["hands"])
    key = sample_key(eid, frame)
    t_rgb = 1_000_000_000 + frame * FRAME_NS
    meta = {
        "key": key, "episode_id": eid, "frame_index": frame, "t_rgb_ns": t_rgb,
        "t_tactile_ns": {h: t_rgb + 1_000 * (i + 1) for i, h in enumerate(hands)},
        "sync_offset_ns": {h: 1_000 * (i + 1) for i, h in enumerate(hands)},
        "hands": {"left": "left" in hands, "right": "right" in hands},
    }
    members = {"json": json.dumps(meta, sort_keys=True).encode(),
               "rgb.jpg": encode_rgb(synthetic_rgb(seed, eid, frame), quality=95)}
    layouts = episode_layouts(spec)
    for hand in ("left", "right"):
        if hand in hands:
            m = synthetic_tactile(seed, eid, frame, hand, coverages[layouts[hand]])
            members[f"tactile_{hand}.exr"] = encode_tactile(m, where=f"{key}.tactile_{hand}")
    if bend_dims:
        for hand in ("left", "right"):
            if hand in hands:
                buf = io.BytesIO()
                np.save(buf, _rng(seed, eid, frame, 3).random(bend_dims, dtype=np.float32))
                members[f"bend_{hand}.npy"] = buf.getvalue()
    return members


def episode_layouts(spec: dict) -> dict[str, str]:
    given = dict(spec.get("layouts") or {})
    return {h: given.get(h, DEFAULT_LAYOUT) for h in spec["hands"]}


def write_synthetic_dataset(root, episodes: list[dict], seed: int = 0,
                            coverages: dict[str, np.ndarray] | None = None,
                            canonical: CanonicalArtifact | None = None,
                            samples_per_shard: int = 4, episodes_per_unit: int = 2,
                            bend_dims: int = 0, fps: float = 30.0) -> Path:
    """Write and commit a dataset at `root`; returns root as a Path.

    episodes: [{"episode_id", "task", "scene", "hands": ("right",) | ("left","right"),
    "num_frames", optional "layouts": {hand: layout_id}, optional "source_split"}].
    Episodes are grouped `episodes_per_unit` per work unit; small
    `samples_per_shard` makes episodes span shards.
    """
    root = Path(root)
    coverages = dict(coverages or {})
    for spec in episodes:
        if spec["num_frames"] < 1:
            raise ValueError(f"episode {spec['episode_id']}: num_frames must be >= 1")
        for hand, layout_id in episode_layouts(spec).items():
            coverages.setdefault(layout_id, np.ones((CANVAS, CANVAS), np.uint8))
    layout_hands = {}
    for spec in episodes:
        for hand, layout_id in episode_layouts(spec).items():
            layout_hands.setdefault(layout_id, hand)

    units = []
    for u, start in enumerate(range(0, len(episodes), episodes_per_unit)):
        group = episodes[start:start + episodes_per_unit]
        with ShardWriter(root / "shards", unit=u, samples_per_shard=samples_per_shard) as writer:
            for spec in group:
                for frame in range(spec["num_frames"]):
                    writer.add_sample(sample_key(spec["episode_id"], frame),
                                      synthetic_members(spec, frame, seed, coverages, bend_dims))
        records = []
        for spec in group:
            rec = {
                "episode_id": spec["episode_id"], "source": "synthetic",
                "source_ref": f"memory::{spec['episode_id']}", "task": spec["task"], "scene": spec["scene"],
                "hands": list(spec["hands"]), "layouts": episode_layouts(spec),
                "num_frames": spec["num_frames"], "fps": fps, "stats": {}, "sync": {},
                "dropped_frames": 0, "notes": [],
            }
            if "source_split" in spec:
                rec["source_split"] = spec["source_split"]
            records.append(rec)
        units.append(UnitResult(unit=u, shards=writer.shards, samples=writer.samples, episodes=records))

    layouts = [LayoutArtifact(layout_id=lid, document={"layout_id": lid, "hand": layout_hands.get(lid, "right"),
                                                       "synthetic": True},
                              coverage=np.asarray(cov, np.uint8))
               for lid, cov in coverages.items()]
    commit_dataset(root, units, layouts=layouts, canonical=canonical or default_canonical(),
                   codec=DEFAULT_CODEC_INFO, sources=[{"name": "synthetic", "seed": seed}],
                   created="2000-01-01T00:00:00+00:00")
    return root


def rewrite_manifest(root, manifest: dict) -> None:
    """Overwrite the current version's manifest in BOTH places (dataset.json, the pointer, and
    versions/vN.json), as a test that edits a committed dataset by hand must to keep them equal."""
    data = json.dumps(manifest, indent=2) + "\n"
    (Path(root) / MANIFEST_FILE).write_text(data)
    (Path(root) / version_manifest_file(manifest["version"])).write_text(data)


def edit_split(root, name: str, edit) -> None:
    """Edit the current version's split file in place (`edit(doc)`), and its sha256 in the manifest
    (both copies, when the version lists it) so that only the split content checks can notice."""
    path = split_path(root, name)
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    manifest = json.loads((Path(root) / MANIFEST_FILE).read_text())
    if name in manifest.get("splits", {}):
        manifest["splits"][name]["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
        rewrite_manifest(root, manifest)


def commit_split(root, name: str, parts: dict[str, list[str]]) -> int:
    """Commit a new version whose split NAME places episodes as given (a hand-made split, for
    reader / torch tests that need particular parts). Returns the new version number."""
    from htdata.store.snapshot import commit_parts, open_snapshot

    snap = open_snapshot(root)
    data = (json.dumps({"name": name, "parts": {p: {"episodes": ids} for p, ids in parts.items()}}) + "\n").encode()
    return commit_parts(root, snap.parts(), {}, snap, f"test: split {name}",
                        splits=lambda episodes, sha: {name: data})["version"]


# --------------------------------------------------------------------------- episode tables
# The episode lists the dataset tests share (write_synthetic_dataset specs), built by one factory.

HAND_CODES = {"R": ("right",), "L": ("left",), "LR": ("left", "right")}
GLOVE_LAYOUTS = {"left": "glove_l", "right": "glove_r"}


def episode_table(*rows: tuple, glove_layouts: bool = False) -> list[dict]:
    """Episode specs from (episode_id, task, scene, hands "R" | "L" | "LR", num_frames) rows.

    glove_layouts: each hand gets its own layout id (GLOVE_LAYOUTS); otherwise
    every hand uses DEFAULT_LAYOUT (full coverage unless `coverages` says otherwise).
    """
    specs = []
    for episode_id, task, scene, hands, num_frames in rows:
        spec = {"episode_id": episode_id, "task": task, "scene": scene, "hands": HAND_CODES[hands],
                "num_frames": num_frames}
        if glove_layouts:
            spec["layouts"] = {h: GLOVE_LAYOUTS[h] for h in HAND_CODES[hands]}
        specs.append(spec)
    return specs


# Three episodes covering one hand, two hands and a single frame: reader, torch and remote tests.
MIXED_HANDS_ROWS = (("ep_a", "pour", "kitchen", "R", 5), ("ep_b", "wipe", "office", "LR", 4),
                    ("ep_c", "pour", "office", "L", 1))
MIXED_HANDS_EPISODES = episode_table(*MIXED_HANDS_ROWS, glove_layouts=True)


def mixed_hands_coverages() -> dict[str, np.ndarray]:
    """Partial coverages of the two gloves of MIXED_HANDS_EPISODES (glove_r, glove_l): maps hold zeros outside."""
    right = np.zeros((224, 224), np.uint8)
    right[20:200, 30:190] = 1
    left = np.zeros((224, 224), np.uint8)
    left[40:220, 10:150] = 1
    return {"glove_r": right, "glove_l": left}
MIXED_HANDS_ONE_LAYOUT_EPISODES = episode_table(*MIXED_HANDS_ROWS)
# The preview's contact sheet: an odd frame count, both hands, a one-frame left-only episode.
PREVIEW_EPISODES = episode_table(("ep_r", "pour", "kitchen", "R", 7), ("ep_lr", "wipe", "office", "LR", 3),
                                 ("ep_one", "wipe", "office", "L", 1))
# Five episodes, three tasks (one to hold out as OOD), one- and two-hand: split / validate tests.
SPLIT_EPISODES = episode_table(("ep_a", "pour", "kitchen", "R", 5), ("ep_b", "wipe", "office", "LR", 4),
                               ("ep_c", "wipe", "kitchen", "R", 3), ("ep_d", "grasp", "office", "R", 3),
                               ("ep_e", "grasp", "office", "R", 1))
# Five episodes for the trainer: "grab" is the held-out task, both hands seen.
TRAIN_EPISODES = episode_table(("ep_a", "pour", "kitchen", "R", 6), ("ep_b", "pour", "office", "LR", 5),
                               ("ep_c", "wipe", "kitchen", "R", 4), ("ep_d", "wipe", "office", "L", 4),
                               ("ep_e", "grab", "office", "R", 3))


# --------------------------------------------------------------------------- raw recordings + the ingest CLI
# Tiny raw corpora in the three source formats (htdata.synthetic.formats), for the ingest, Ray and
# benchmark tests: 3 OpenTouch clips (39 frames), 2 TouchAnything episodes (11), 1 native (9).

PERIOD = 33_333_333
COLOURS = [(200, 40, 90), (30, 160, 220), (250, 250, 10), (90, 90, 90)]


def small_pipeline(tmp_path: Path, name: str, samples_per_shard: int = 8) -> Path:
    """A shipped pipeline with a tiny shard size (more units, more shards)."""
    text = (PIPELINES_DIR / f"{name}.toml").read_text()
    text = text.replace("samples_per_shard = 256", f"samples_per_shard = {samples_per_shard}")
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def ot_clip(demo_id: str, t: int, colour, pressure: np.ndarray | None = None) -> OpenTouchClip:
    if pressure is None:
        rng = np.random.default_rng(len(demo_id) * 7 + t)
        pressure = rng.uniform(1000, 3072, size=(t, 16, 16)).astype(np.float32)
    frames = [np.full((48, 64, 3), colour, np.uint8) for _ in range(t)]
    return OpenTouchClip(demo_id, np.arange(t, dtype=np.int64) * PERIOD + 10**12, pressure, frames)


def make_opentouch(root: Path, bad: bool = False) -> Path:
    clips = [ot_clip("demo_01", 12, COLOURS[0]), ot_clip("demo_02", 7, COLOURS[1]),
             ot_clip("demo_003", 20, COLOURS[2])]
    write_opentouch_scene(root / "home_kitchen_p1.hdf5", clips)
    rows = [{"id": f"home_kitchen_p1::{c.demo_id}", "action": a} for c, a in zip(clips, ["pour", "cut", "wipe"])]
    if bad:
        nan = np.full((6, 16, 16), np.nan, np.float32)
        bad_clips = [ot_clip("demo_01", 6, COLOURS[3], pressure=nan),   # all-NaN
                     ot_clip("demo_02", 0, COLOURS[3]),                  # zero frames
                     ot_clip("demo_03", 6, COLOURS[3])]                  # undecodable JPEG at frame 4
        write_opentouch_scene(root / "office_desk_p2.hdf5", bad_clips)
        with h5py.File(root / "office_desk_p2.hdf5", "r+") as f:
            f["data/demo_03/rgb_images_jpeg"][4] = np.frombuffer(b"not a jpeg at all", np.uint8)
        rows += [{"id": f"office_desk_p2::demo_0{i}", "action": "type"} for i in (1, 2, 3)]
    write_opentouch_annotations(root / "annotations.csv", rows)
    return root


def make_two_scene_opentouch(root: Path) -> Path:
    """make_opentouch's scene (3 clips) and a second good one (office_desk_p2, 2 clips), one label table."""
    make_opentouch(root)
    clips = [ot_clip("demo_01", 5, COLOURS[3]), ot_clip("demo_02", 6, COLOURS[0])]
    write_opentouch_scene(root / "office_desk_p2.hdf5", clips)
    rows = [{"id": f"home_kitchen_p1::demo_{d}", "action": a} for d, a in (("01", "pour"), ("02", "cut"),
                                                                           ("003", "wipe"))]
    rows += [{"id": f"office_desk_p2::{c.demo_id}", "action": "type"} for c in clips]
    write_opentouch_annotations(root / "annotations.csv", rows)
    return root


def make_touchanything(root: Path, truncated: bool = False) -> Path:
    from htdata.glove.layouts import load_layout

    for n, (scene, task, traj) in enumerate([("Home", "plug_usb", "20260320_135743_682"),
                                             ("Office", "open_drawer", "20260321_101010_001")]):
        t = 5 + n
        grids = {}
        for hand in ("left", "right"):
            lay = load_layout(f"touchanything_{hand}_21x21")
            g = np.full((t, 21, 21), np.nan, np.float32)
            g[:, lay.live_mask] = np.linspace(0, 1, t, dtype=np.float32)[:, None]
            g[:, lay.bend_cells[:, 0], lay.bend_cells[:, 1]] = 0.25
            grids[hand] = g
        ep = TouchAnythingEpisode(left_grid=grids["left"], right_grid=grids["right"],
                                  chest_frames=[np.full((480, 640, 3), COLOURS[n], np.uint8)] * t,
                                  ts_epoch_s=1.7e9 + np.arange(t) / 30.0)
        folder = root / scene / task / traj
        write_touchanything_episode(folder, ep, wrist_videos=False)
        if truncated and n == 1:
            npz = folder / "pressure_grids.npz"
            data = npz.read_bytes()
            npz.write_bytes(data[: len(data) // 2])
    return root


def make_native(root: Path, wrong_grid: bool = False) -> Path:
    t_video = np.arange(9, dtype=np.int64) * PERIOD
    t_glove = np.arange(0, 9 * PERIOD, 10_000_000, dtype=np.int64)   # 100 Hz glove, 30 Hz video
    values = np.full((t_glove.size, 16, 16), 1536.0, np.float32)
    rec = NativeRecording(task="grasp_cup", scene="lab", video_storage="jpeg",
                          video_frames=[np.full((40, 40, 3), COLOURS[0], np.uint8)] * 9,
                          video_timestamps_ns=t_video,
                          hands={"right": NativeHand("opentouch_right_16x16", values, t_glove)})
    write_native_recording(root / "rec_good", rec)
    if wrong_grid:
        rec.hands = {"right": NativeHand("opentouch_right_16x16", np.zeros((t_glove.size, 8, 8), np.float32),
                                         t_glove)}
        rec.video_frames = [np.full((40, 40, 3), COLOURS[1], np.uint8)] * 9
        write_native_recording(root / "rec_wrong_grid", rec)
    return root


def ingest_cli(*args, workers: int = 0) -> int:
    """In-process CLI; workers=0 runs units inline (fast), >0 uses the process pool."""
    from htdata.cli import main

    return main(["ingest", "--workers", str(workers), "--quiet", *map(str, args)])


def ingest_crashing_at_unit(unit: int, *args) -> subprocess.CompletedProcess:
    """The ingest CLI, inline, in a subprocess whose unit `unit` dies as a kill -9 would
    (HTDATA_TEST_FAULT=crash: returncode 137); the units before it finish and stay for a resume."""
    env = {**os.environ, "HTDATA_TEST_FAULT_UNIT": str(unit), "HTDATA_TEST_FAULT": "crash"}
    return subprocess.run([sys.executable, "-m", "htdata.cli", "ingest", "--workers", "0", "--quiet",
                           *map(str, args)], env=env, capture_output=True, text=True)


def temp_leftovers(out: Path) -> list[str]:
    return sorted(str(p.relative_to(out)) for p in out.rglob("*")
                  if p.name.endswith(".tmp") or p.name.startswith("spool-"))


def commit_dataset(root: str | os.PathLike, units: list[UnitResult], layouts: list[LayoutArtifact],
                   canonical: CanonicalArtifact, codec: dict, sources: list[dict],
                   created: str | None = None, htdata_version: str | None = None,
                   command: str = "commit") -> dict:
    """Commit `units` as a new dataset version at `root` (the first, on a fresh directory). Returns its manifest.

    Shards must already sit in ROOT/shards (ShardWriter put them there); their
    sizes are checked against the records. The version holds exactly these
    units; writers that keep a parent's episodes (ingest's append, rm, trim)
    build their parts and call snapshot.commit_parts themselves.
    """
    layout_entries, canonical_entry = write_layout_files(root, layouts, canonical)
    fields = {"sources": list(sources), "layouts": layout_entries, "canonical": canonical_entry, "codec": codec}
    parts = [part_from_unit(u) for u in sorted(units, key=lambda u: u.unit)]
    return commit_parts(root, parts, fields, current_snapshot(root), command, created=created,
                        htdata_version=htdata_version, splits=lambda eps, sha: {})


# --------------------------------------------------------------------------- a glove-only raw-count dataset
RAWGLOVE_PIPELINE = ('name = "rawknit"\n[adapter]\nname = "native"\n[adapter.params]\n'
                     '[tactile]\nkeep_raw = true\n'
                     '[normalise.rawknit_left_32x32]\nbaseline = "quietest"\nnoise_k = 3\n'
                     '[normalise.rawknit_right_32x32]\nbaseline = "quietest"\nnoise_k = 3\n')


def ingest_rawglove(tmp: Path, clips: int = 2) -> Path:
    """The sample raw-count glove (htdata.synthetic.rawglove: glove only, no RGB, faint 32x32 counts), its first
    `clips` clips ingested with a pipeline named "rawknit" (not its adapter's name) that sets the quietest
    baseline and a noise floor (so the calibrated contact rule applies); returns the dataset path."""
    import shutil

    from htdata.synthetic.rawglove import write_rawglove

    raw = tmp / "rawglove"
    write_rawglove(raw)
    for folder in sorted(p for p in raw.iterdir() if p.is_dir() and p.name != "layouts")[clips:]:
        shutil.rmtree(folder)
    pipe = tmp / "rawknit.toml"
    pipe.write_text(RAWGLOVE_PIPELINE)
    out = tmp / "rawknit_ds"
    if ingest_cli("--pipeline", pipe, "--layouts", raw / "layouts", raw, out) != 0:
        raise RuntimeError(f"{raw}: the raw-count glove sample did not ingest")
    return out
