"""Windows at the glove's own rate: the last `window` glove rows up to each paired frame, as maps.

`TactileWindowDataset` stacks consecutive SAMPLES (the camera's rate). A
100 Hz glove beside a 30 Hz camera records ~3 rows per sample, all stored
exactly in format 3 (htdata/ingest/fullrate.py); for frame prediction at
the glove's rate, `GloveRateWindowDataset` gives, for each sample with
the hand's paired row, the `window` distinct glove rows ending at that row
in the episode's full-rate stream (htdata.read.rawstream.episode_stream),
rendered through the episode's recorded calibration and the dataset's
raster mode. Item: tactile (window,1,224,224) f32, t_ns (window,) int64
(recorded glove timestamps), coverage, regions, hand, task, scene, episode,
frame and index of the paired sample. Samples whose paired row has fewer
than `window - 1` rows before it in the episode are not items (no padding).
Building the item list reads every selected sample's JSON member once;
each worker keeps the streams of the two episodes it read last. Which samples
and which version: one `options=ItemOptions(...)`, as the other torch datasets
(htdata/read/itemoptions.py); the old keywords warn until htdata/_moved.py's REMOVED_IN.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

try:
    import torch
except ModuleNotFoundError as exc:   # the data core installs without torch
    raise ModuleNotFoundError(f"{__name__} needs torch: pip install 'htdata[torch]' (torch==2.13.0)") from exc

from htdata._moved import folded_keywords
from htdata.errors import ArgumentError
from htdata.format.table import JSON_MEMBER, SIZE_FIELDS, decode_member, raw_member
from htdata.format.tactilecodec import check_served_maps
from htdata.read import keys
from htdata.read.itemoptions import ItemOptions, item_options, keywords_as_options, streamed_only
from htdata.read.keys import HAND_IDS
from htdata.read.rawstream import RawStream, episode_stream
from htdata.read.torchdata import HAND_NAMES, _ItemDataset
from htdata.read.torchitems import ItemBuilder

KEEP_STREAMS = 2
# the signature before `options=` (these keywords warn until htdata/_moved.py's REMOVED_IN)
_OLD_ARGS = ("split", "part", "hands", "version")


class GloveRateWindowDataset(_ItemDataset):
    """See the module docstring.

    Args:
        root: the dataset folder or URL.
        window: glove rows per item (>= 1), ending at each sample's paired row.
        options: which samples, from which version (htdata.read.itemoptions.ItemOptions; None: its defaults).
            It reads `split`, `part`, `hands` and `version`; an item is always the tactile maps rendered from
            the raw rows with its constants, so `rgb_float`, `frames` and the RGB member do not apply, and
            `maps_from="stored"`, `members` without "tactile", `constants="once"` and an `on_error` other
            than "raise" are refused.

    Raises:
        ArgumentError: `window` < 1; `options` is not an ItemOptions, or asks for what is refused above.
    """

    @folded_keywords("options", keywords_as_options, _OLD_ARGS, _OLD_ARGS)
    def __init__(self, root, window: int = 4, *, options: ItemOptions | None = None):
        if window < 1:
            raise ArgumentError(f"window must be >= 1, got {window}")
        o = streamed_only(item_options(options), "GloveRateWindowDataset")
        if o.maps_from == "stored" or keys.TACTILE not in o.members or o.constants != "item":
            raise ArgumentError(f"GloveRateWindowDataset items are tactile maps rendered from the raw rows, with "
                                f"their constants: options cannot ask maps_from='stored', members without "
                                f"'tactile' or constants='once' (got maps_from={o.maps_from!r}, "
                                f"members={o.members}, constants={o.constants!r})")
        self.window = window
        self.options = o
        self.hands = o.hands
        # the builder renders every map from the raw rows and decodes no RGB frame
        self._builder = ItemBuilder(root, o.replace(maps_from="raw", members=(keys.TACTILE,)))
        reader = self._builder.reader
        items = []   # (sample index, hand id, position of the paired row in the episode stream)
        for pos in reader.episode_positions(o.split, o.part):
            first, n = reader.episode_range(pos)
            for hand in self.hands:
                if hand not in reader.episodes[pos]["hands"]:
                    continue
                items += [(i, HAND_IDS[hand], p) for i, p in self._paired_positions(first, n, hand)
                          if p >= window - 1]
        self.items = np.asarray(items, np.int64).reshape(-1, 3)
        self._streams: OrderedDict[tuple[int, str], RawStream] = OrderedDict()

    def _paired_positions(self, first: int, n: int, hand: str) -> list[tuple[int, int]]:
        """(sample, position of its paired row among the episode's distinct rows in time order)."""
        reader = self._builder.reader
        rows, paired = [], []
        for i in range(first, first + n):
            if reader.index[i][SIZE_FIELDS[raw_member(hand)]] == 0:
                continue
            meta = decode_member(JSON_MEMBER, reader.sample(i, (JSON_MEMBER,))[JSON_MEMBER], reader.key(i))
            rows += zip(meta["raw_t_ns"][hand], meta["raw_row"][hand])
            if hand in (meta.get("raw_paired") or {}):
                k = meta["raw_paired"][hand]
                paired.append((i, (meta["raw_t_ns"][hand][k], meta["raw_row"][hand][k])))
        order = {row: p for p, row in enumerate(sorted(set(rows)))}
        return [(i, order[row]) for i, row in paired]

    def _stream(self, episode: int, hand: str) -> RawStream:
        key = (episode, hand)
        if key not in self._streams:
            self._streams[key] = episode_stream(self._builder.reader, episode, hand)
            while len(self._streams) > KEEP_STREAMS:
                self._streams.popitem(last=False)
        self._streams.move_to_end(key)
        return self._streams[key]

    def __getitem__(self, i: int) -> dict:
        index, hand_id, pos = self.items[i].tolist()
        hand = HAND_NAMES[hand_id]
        builder = self._builder
        row = builder.reader.row(index)
        stream = self._stream(row.episode, hand)
        normaliser, raster = builder.renderer.parts_for(row.episode, hand)
        rows = stream.rows[pos - self.window + 1:pos + 1]
        values, _ = normaliser.apply(rows, rows=stream.source_row[pos - self.window + 1:pos + 1])
        out = builder.ids(row, index, hand)
        del out[keys.HAS_RGB]
        maps = check_served_maps(raster.render(values), f"{builder.reader.root}: {builder.reader.key(index)} ({hand})")
        out[keys.TACTILE] = torch.from_numpy(maps[:, None])
        out[keys.T_NS] = torch.from_numpy(stream.t_ns[pos - self.window + 1:pos + 1].copy())
        return out
