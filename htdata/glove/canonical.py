"""The canonical hand: the 224x224 frame every glove is drawn into (schemas/layouts/canonical_hand.json).

Places are axis-aligned rectangles with region ids; groups (thumb, fingers,
palm) are the bounding boxes of their places; part ids drive stage-2 masking.
docs/LAYOUTS.md "The canonical hand" is the reference.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from htdata.format.canvas import CANVAS
from htdata.format.table import CANONICAL_FILE
from htdata.resources import LAYOUTS_DIR, validate_json

PART_NAMES: dict[int, str] = {1: "thumb", 2: "index", 3: "middle", 4: "ring", 5: "little", 6: "palm"}


GROUPS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "little", "palm")


Rect = tuple[int, int, int, int]


def frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class CanonicalHand:
    """The 224x224 template: places, their region ids and the label maps."""

    places: dict[str, Rect]
    region_ids: dict[str, int]
    region_map: np.ndarray  # (224,224) uint8 region id, 0 = outside
    part_map: np.ndarray  # (224,224) uint8 part id, 0 = outside
    part_names: dict[int, str]
    part_of_region: dict[int, int]  # region id -> part id
    groups: dict[str, Rect]  # group name -> bounding box of its places
    source: dict = field(repr=False, default_factory=dict)

    def target_rect(self, target: str) -> Rect:
        """Rectangle a block is resampled over: a place's rect or a group's bbox."""
        if target in self.places:
            return self.places[target]
        if target in self.groups:
            return self.groups[target]
        raise KeyError(target)

    def target_mask(self, target: str) -> np.ndarray:
        """Pixels a block targeting `target` may draw on (only inside places)."""
        if target in self.places:
            return self.region_map == self.region_ids[target]
        if target in self.groups:
            return self.part_map == GROUPS.index(target) + 1
        raise KeyError(target)

    def to_dict(self) -> dict:
        return json.loads(json.dumps(self.source))


def _bbox(rects: list[Rect]) -> Rect:
    a = np.array(rects)
    return (int(a[:, 0].min()), int(a[:, 1].min()), int(a[:, 2].max()), int(a[:, 3].max()))


def _rects_overlap(a: Rect, b: Rect) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def parse_canonical(doc: dict, where: str = CANONICAL_FILE) -> CanonicalHand:
    """Validate a canonical template document and build its label maps."""
    validate_json(doc, "canonical_hand", where)
    places: dict[str, Rect] = {}
    region_ids: dict[str, int] = {}
    for name, spec in doc["places"].items():
        x0, y0, x1, y1 = (int(v) for v in spec["rect"])
        if not (0 <= x0 < x1 <= CANVAS and 0 <= y0 < y1 <= CANVAS):
            raise ValueError(f"{where}: place {name!r}: rect {spec['rect']} is empty or outside the canvas")
        places[name] = (x0, y0, x1, y1)
        region_ids[name] = int(spec["region_id"])
    if sorted(region_ids.values()) != list(range(1, len(places) + 1)):
        raise ValueError(f"{where}: region ids must be exactly 1..{len(places)}, got {sorted(region_ids.values())}")
    names = list(places)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if _rects_overlap(places[a], places[b]):
                raise ValueError(f"{where}: places {a!r} and {b!r} overlap")
    groups = {g: _bbox([r for n, r in places.items() if n.split(".")[0] == g]) for g in GROUPS}
    for g, box in groups.items():
        for n, r in places.items():
            if n.split(".")[0] != g and _rects_overlap(box, r):
                raise ValueError(f"{where}: bounding box of group {g!r} {box} overlaps place {n!r}")

    region_map = np.zeros((CANVAS, CANVAS), np.uint8)
    part_map = np.zeros((CANVAS, CANVAS), np.uint8)
    part_of_region: dict[int, int] = {}
    for name, (x0, y0, x1, y1) in places.items():
        part = GROUPS.index(name.split(".")[0]) + 1
        region_map[y0:y1, x0:x1] = region_ids[name]
        part_map[y0:y1, x0:x1] = part
        part_of_region[region_ids[name]] = part
    return CanonicalHand(places=places, region_ids=region_ids, region_map=frozen(region_map),
                         part_map=frozen(part_map), part_names=dict(PART_NAMES),
                         part_of_region=part_of_region, groups=groups, source=doc)


@lru_cache(maxsize=1)
def load_canonical() -> CanonicalHand:
    """The shipped template (`schemas/layouts/canonical_hand.json`), cached."""
    path = LAYOUTS_DIR / CANONICAL_FILE
    return parse_canonical(json.loads(path.read_text()), str(path))
