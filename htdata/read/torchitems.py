"""What a torch item carries: the members asked for, and per-layout constants per item or once.

A training step reads only part of an item: HandTouch's stage 1 reads the
tactile map and its coverage, never the RGB frame. So a dataset is asked for
its `members` (`("tactile", "rgb")` by default; `("tactile",)` skips the JPEG
decode; `("rgb",)` skips the map) and how to ship per-layout constants:

- `constants="item"` (default): every item carries coverage (1,224,224) f32 and
  regions (224,224) u8 plus one 0-d tensor per id, as before.
- `constants="once"`: an item carries only its members and `ids`, one (8,)
  int64 tensor in `keys.ID_FIELDS` order (hand, task, scene, episode, frame,
  index, has_rgb, layout). The dataset's `constants()` (an `ItemConstants`:
  every layout's coverage as uint8 and the region map, ~50 KB each) is sent to
  the device once, and `expand_batch(batch, constants)` rebuilds, on whatever
  device the batch is on, exactly the batch `constants="item"` gives (a gather
  of the coverage table by layout id). Between processes this moves ~200 KB
  per tactile-only item instead of ~450 KB (+150 KB of RGB when asked for).

Items are assembled in numpy and wrapped with torch.from_numpy (see ItemBuilder).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

try:
    import torch
except ModuleNotFoundError as exc:   # the data core installs without torch
    raise ModuleNotFoundError(f"{__name__} needs torch: pip install 'htdata[torch]' (torch==2.13.0)") from exc

from htdata.format.canvas import CANVAS
from htdata.format.table import JSON_MEMBER, MEMBER_ORDER, RGB_MEMBER, decode_member, raw_member, tactile_member
from htdata.read import keys
from htdata.read.itemoptions import ItemOptions
from htdata.read.keys import HAND_IDS
from htdata.read.rawstream import MapServing, RawMapRenderer
from htdata.read.reader import DatasetReader, SampleRow

_RGB_POS = MEMBER_ORDER.index(RGB_MEMBER)   # in SampleRow.sizes


def _long(value: int) -> torch.Tensor:
    # 0-d int64 via numpy: ~3x cheaper than torch.tensor(value) per call.
    return torch.from_numpy(np.array(value, dtype=np.int64))


@dataclass
class ItemConstants:
    """Per-layout constants of one dataset version, sent once (constants="once").

    Args:
        layouts: layout ids; an item's `layout` id is a position in it.
        coverage: (L,1,224,224) uint8 0/1, one coverage mask per layout.
        regions: (224,224) uint8 part ids of the canonical hand.
    """
    layouts: tuple[str, ...]       # layout id -> position = the `layout` id an item carries
    coverage: torch.Tensor         # (L,1,224,224) uint8 0/1
    regions: torch.Tensor          # (224,224) uint8 part ids

    def to(self, device, non_blocking: bool = False) -> "ItemConstants":
        """A copy on `device`.

        Args:
            device: a torch device (or its name).
            non_blocking: passed on to Tensor.to (pinned memory -> GPU without waiting).
        """
        return ItemConstants(self.layouts, self.coverage.to(device, non_blocking=non_blocking),
                             self.regions.to(device, non_blocking=non_blocking))


def expand_batch(batch: dict, constants: ItemConstants) -> dict:
    """A collated constants="once" batch -> the batch constants="item" gives (same keys, dtypes, values).

    Runs where the batch is: move `constants` to the batch's device once (`.to`), not per step.

    Args:
        batch: a collated batch; one without `ids` (constants="item") is returned as it is.
        constants: the dataset's `constants()`, on the batch's device.
    """
    if keys.IDS not in batch:
        return batch
    ids = batch[keys.IDS]
    out = {k: v for k, v in batch.items() if k != keys.IDS}
    for col, name in enumerate(keys.ID_FIELDS):
        if name != keys.LAYOUT:
            out[name] = ids[:, col].bool() if name == keys.HAS_RGB else ids[:, col]
    layout = ids[:, keys.ID_FIELDS.index(keys.LAYOUT)]
    out[keys.COVERAGE] = constants.coverage[layout].float()
    out[keys.REGIONS] = constants.regions.expand(ids.shape[0], -1, -1)
    return out


class ItemBuilder:
    """Decodes (sample, hand) into item tensors with the fewest copies and no torch kernels.

    Items are assembled in numpy and wrapped with torch.from_numpy: torch ops
    such as stack / div run on torch's OpenMP pool, whose threads spin against
    other processes on a shared machine (measured: torch.stack of three
    (1,224,224) maps took 6-19 ms instead of 0.02 ms). The json member is not
    read: every id an item carries comes from index.npy and episodes.jsonl.

    Args:
        root: the dataset folder or URL.
        options: the dataset's ItemOptions (version, rgb_float, maps_from, members, constants are read here).
    """

    def __init__(self, root, options: ItemOptions):
        self.options = options
        self.reader = DatasetReader(root, version=options.version)
        self.rgb_float = options.rgb_float
        self.members = options.members
        self.constants_mode = options.constants
        self.serving = MapServing.choose(self.reader.manifest, options.maps_from, where=str(self.reader.root))
        self.renderer = RawMapRenderer(self.reader) if self.serving.rendered else None
        self._task_ids = {t: i for i, t in enumerate(self.reader.manifest["tasks"])}
        self._scene_ids = {s: i for i, s in enumerate(self.reader.manifest["scenes"])}
        self._layout_ids = {lay: i for i, lay in enumerate(sorted(self.reader.manifest["layouts"]))}
        self._coverage: dict[str, torch.Tensor] = {}
        self._regions: torch.Tensor | None = None

    @property
    def wants_rgb(self) -> bool:
        """Whether items carry the RGB frame."""
        return keys.RGB in self.members

    @property
    def wants_tactile(self) -> bool:
        """Whether items carry the tactile map."""
        return keys.TACTILE in self.members

    def coverage(self, layout_id: str) -> torch.Tensor:
        """(1,224,224) float32 coverage of a layout, cached.

        Args:
            layout_id: a layout of the version (manifest "layouts").
        """
        if layout_id not in self._coverage:
            cov = self.reader.coverage(layout_id).astype(np.float32)
            self._coverage[layout_id] = torch.from_numpy(cov)[None]
        return self._coverage[layout_id]

    def regions(self) -> torch.Tensor:
        """(224,224) uint8 part ids of the canonical hand, cached."""
        if self._regions is None:
            self._regions = torch.from_numpy(np.ascontiguousarray(self.reader.region_map))
        return self._regions

    def constants(self) -> ItemConstants:
        """Every layout's coverage (uint8) and the region map, for constants="once" batches (`expand_batch`)."""
        layouts = tuple(self._layout_ids)
        cov = np.stack([self.reader.coverage(lay) for lay in layouts]) if layouts else \
            np.zeros((0, CANVAS, CANVAS), np.uint8)
        return ItemConstants(layouts, torch.from_numpy(np.ascontiguousarray(cov, np.uint8))[:, None], self.regions())

    def empty_rgb(self, n: int) -> np.ndarray | None:
        """(n,3,224,224) rgb buffer (u8, or f32 with rgb_float) to decode into; None when RGB is not asked for.

        Args:
            n: frames the buffer holds.
        """
        if not self.wants_rgb:
            return None
        return np.empty((n, 3, CANVAS, CANVAS), np.float32 if self.rgb_float else np.uint8)

    def put_rgb(self, out: np.ndarray, rgb_hwc: np.ndarray) -> None:
        """HWC uint8 -> CHW in `out` (scaled to [0,1] when out is float).

        cv2.split writes straight into the three planes (~4x faster than a
        numpy transpose copy); the pointer check guards against a binding that
        allocated new planes instead.

        Args:
            out: (3,224,224) uint8 or float32 buffer written in place.
            rgb_hwc: (224,224,3) uint8 decoded JPEG.
        """
        planes = out if out.dtype == np.uint8 else np.empty(out.shape, np.uint8)
        written = cv2.split(rgb_hwc, [planes[0], planes[1], planes[2]])
        if any(w.ctypes.data != p.ctypes.data for w, p in zip(written, planes)):
            planes[...] = rgb_hwc.transpose(2, 0, 1)
        if planes is not out:
            np.divide(planes, np.float32(255.0), out=out, dtype=np.float32)

    def suffixes(self, hands) -> tuple[str, ...]:
        """Members an item of these hands reads (the JPEG only when RGB is asked for).

        Args:
            hands: the hands whose maps are read.
        """
        rgb = (RGB_MEMBER,) if self.wants_rgb else ()
        if not self.wants_tactile:
            return rgb
        maps = tuple(tactile_member(h) for h in hands)
        return (*rgb, JSON_MEMBER, *maps, *(raw_member(h) for h in hands)) if self.serving.rendered else (*rgb, *maps)

    def tactile_map(self, members: dict[str, bytes], hand: str, episode: int, where: str) -> np.ndarray:
        """(224,224) float32 map of `hand`: rendered from raw rows or the stored EXR decoded (`serving`).

        Args:
            members: the sample's members as read (`suffixes`).
            hand: "left" or "right".
            episode: the sample's episode position (its calibration renders the map).
            where: the sample, named by errors.
        """
        if self.serving.rendered and raw_member(hand) in members:
            return self.renderer.render(episode, hand, members, where)
        if self.serving.raw_required:
            raise KeyError(f"{where} has no raw {hand} rows (maps_from='raw')")
        suffix = tactile_member(hand)
        if suffix not in members:
            raise KeyError(f"{where} has no {hand} tactile map")
        return decode_member(suffix, members[suffix], where)

    def decode_into(self, members: dict[str, bytes], hands, where: str, rgb_out, episode: int) -> list:
        """Decode the JPEG once into each hand's rgb buffer (zeros when the sample has none) when RGB
        is asked for; each hand's map (None when tactile is not asked for).

        Args:
            members: the sample's members as read (`suffixes`).
            hands: the hands to decode, in item order.
            where: the sample, named by errors.
            rgb_out: one (3,224,224) buffer per hand, or None when RGB is not asked for.
            episode: the sample's episode position.
        """
        maps = [self.tactile_map(members, hand, episode, where) if self.wants_tactile else None
                for hand in hands]
        if rgb_out is None:
            return maps
        if RGB_MEMBER in members:
            rgb = decode_member(RGB_MEMBER, members[RGB_MEMBER], where)
        else:
            rgb = np.zeros((CANVAS, CANVAS, 3), np.uint8)
        self.put_rgb(rgb_out[0], rgb)
        for r_out in rgb_out[1:len(hands)]:
            r_out[...] = rgb_out[0]   # each item owns its rgb: a plain copy of the first
        return maps

    def read_frame(self, index: int, hand: str, rgb_out: np.ndarray | None) -> tuple[SampleRow, np.ndarray | None]:
        """Read + decode sample `index` for `hand`: rgb into `rgb_out` (3,224,224) unless None; returns (row, map).

        Args:
            index: the global sample index.
            hand: "left" or "right".
            rgb_out: the buffer the RGB frame is decoded into, or None.
        """
        reader = self.reader
        row, key, members = reader.read_sample(index, suffixes=self.suffixes((hand,)))
        rgb = None if rgb_out is None else [rgb_out]
        return row, self.decode_into(members, (hand,), f"{reader.root}: {key}", rgb, row.episode)[0]

    def ids(self, row: SampleRow, index: int, hand: str) -> dict:
        """The item's ids (+ coverage and regions with constants="item"; one packed `ids` with "once").

        Args:
            row: the sample's index row (reader.row).
            index: the global sample index.
            hand: the item's hand.
        """
        ep = self.reader.episodes[row.episode]
        layout = ep["layouts"][hand]
        if self.constants_mode == "once":
            packed = np.array([HAND_IDS[hand], self._task_ids[ep["task"]], self._scene_ids[ep["scene"]],
                               row.episode, row.frame, index, int(row.sizes[_RGB_POS] > 0),
                               self._layout_ids[layout]], np.int64)
            return {keys.IDS: torch.from_numpy(packed)}
        return {
            keys.COVERAGE: self.coverage(layout),
            keys.REGIONS: self.regions(),
            keys.HAND: _long(HAND_IDS[hand]),
            keys.TASK: _long(self._task_ids[ep["task"]]),
            keys.SCENE: _long(self._scene_ids[ep["scene"]]),
            keys.EPISODE: _long(row.episode),
            keys.FRAME: _long(row.frame),
            keys.INDEX: _long(index),
            keys.HAS_RGB: torch.from_numpy(np.array(row.sizes[_RGB_POS] > 0)),
        }

    def put_members(self, item: dict, tactile: np.ndarray | None, rgb: np.ndarray | None) -> dict:
        """Add the asked-for members to an item: tactile (1,224,224), rgb (3,224,224) (stacked for windows).

        Args:
            item: the item's ids (`ids`), completed in place.
            tactile: the map(s), or None when not asked for.
            rgb: the frame(s), or None when not asked for.
        """
        if tactile is not None:
            item[keys.TACTILE] = torch.from_numpy(tactile)   # decoded map is a fresh array: no copy
        if rgb is not None:
            item[keys.RGB] = torch.from_numpy(rgb)
        return item

    def frame_item(self, index: int, hand: str) -> dict:
        """The whole item of one (sample, hand): ids and the asked-for members.

        Args:
            index: the global sample index.
            hand: "left" or "right".
        """
        rgb = self.empty_rgb(1)
        row, tactile = self.read_frame(index, hand, None if rgb is None else rgb[0])
        return self.put_members(self.ids(row, index, hand), None if tactile is None else tactile[None],
                                None if rgb is None else rgb[0])
