"""What the torch datasets share: which samples make items, from which version, and what an item carries.

`TactileFrameDataset`, `TactileWindowDataset`, `TactileStream` (htdata/read/torchdata.py) and
`GloveRateWindowDataset` (htdata/read/torchglove.py) take one `ItemOptions` as `options=` (its fields are
documented once, on the class), checked once; the item builder (htdata/read/torchitems.py) reads only it. One object serves several datasets:

    opts = ItemOptions(split="main", part="train", members=("tactile",))
    frames = TactileFrameDataset(root, options=opts)
    windows = TactileWindowDataset(root, window=3, options=opts)

The datasets' old keywords (`split=`, `part=`, ...) still work, with a DeprecationWarning, until
htdata/_moved.py's REMOVED_IN (`keywords_as_options`); `ds.torch.frames(split=..., part=...)`
(htdata/read/torchviews.py) takes the fields as keywords and builds the object.

No torch here: an options object can be built (and checked) where torch is not installed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from htdata.errors import ArgumentError
from htdata.format.table import HANDS
from htdata.read import keys
from htdata.read.onerror import check_on_error

FRAME_KINDS = ("paired", "tactile")
MEMBERS = (keys.TACTILE, keys.RGB)     # what a dataset can be asked for
CONSTANTS = ("item", "once")


def check_hands(hands) -> tuple[str, ...]:
    """The hands as a tuple; ArgumentError unless a non-empty subset of ("left", "right") without repeats."""
    hands = tuple(hands)
    if not hands or any(h not in keys.HAND_IDS for h in hands) or len(set(hands)) != len(hands):
        raise ArgumentError(f"hands must be a non-empty subset of ('left', 'right'), got {hands}")
    return hands


def check_frames(frames: str) -> str:
    """`frames`, or ArgumentError unless one of FRAME_KINDS."""
    if frames not in FRAME_KINDS:
        raise ArgumentError(f"frames must be one of {FRAME_KINDS}, got {frames!r}")
    return frames


def check_members(members) -> tuple[str, ...]:
    """The members as a tuple; ArgumentError unless a non-empty subset of MEMBERS without repeats.

    Args:
        members: what an item is asked to carry ("tactile", "rgb").
    """
    members = tuple(members)
    if not members or any(m not in MEMBERS for m in members) or len(set(members)) != len(members):
        raise ArgumentError(f"members must be a non-empty subset of {MEMBERS}, got {members}")
    return members


def check_constants(constants: str) -> str:
    """`constants`, or ArgumentError unless one of CONSTANTS.

    Args:
        constants: "item" (every item carries coverage, regions, ids) or "once" (an `ids` tensor).
    """
    if constants not in CONSTANTS:
        raise ArgumentError(f"constants must be one of {CONSTANTS}, got {constants!r}")
    return constants


@dataclass(frozen=True)
class ItemOptions:
    """Which samples of which version make a torch dataset's items, and what an item carries.

    The one signature of the torch datasets (`options=`); every field is checked when the object is built.

    Args:
        split: the split whose `part` is read (None: every sample).
        part: the part of `split` ("train", "val", ...).
        hands: the hands that make items ("left", "right").
        rgb_float: RGB as float32 in [0,1] instead of uint8.
        version: the committed version to read (None: the current one).
        frames: "paired" (samples with the hand's map and an RGB frame) or "tactile" (+ tactile-only).
        maps_from: "best", "stored" or "raw": where maps come from (htdata.read.rawstream.MapServing checks it
            against the version).
        members: what an item carries: a subset of ("tactile", "rgb").
        constants: "item" (coverage, regions and ids in every item) or "once" (`constants()`, `expand_batch`).
        on_error: a sample that does not read or decode (htdata/read/onerror.py): "raise", "warn" (skip it with
            one warning line naming it) or "skip"; a stream (TactileStream) only: a map-style dataset raises.

    Raises:
        ArgumentError: a field out of its range (hands, frames, members, constants, on_error).
    """
    split: str | None = None
    part: str | None = None
    hands: tuple[str, ...] = HANDS
    rgb_float: bool = False
    version: int | None = None
    frames: str = "paired"
    maps_from: str = "best"
    members: tuple[str, ...] = MEMBERS
    constants: str = "item"
    on_error: str = "raise"

    def __post_init__(self):
        object.__setattr__(self, "hands", check_hands(self.hands))
        object.__setattr__(self, "frames", check_frames(self.frames))
        object.__setattr__(self, "members", check_members(self.members))
        object.__setattr__(self, "constants", check_constants(self.constants))
        check_on_error(self.on_error)

    def replace(self, **changes) -> "ItemOptions":
        """A copy with `changes` (checked like a new one)."""
        return dataclasses.replace(self, **changes)


def streamed_only(options: ItemOptions, dataset: str) -> ItemOptions:
    """`options`, or ArgumentError when they ask a map-style `dataset` to skip samples: it owes an item at
    every index its sampler draws (a stream, TactileStream, can skip)."""
    if options.on_error != "raise":
        raise ArgumentError(f"{dataset} is map-style: every index must give an item, so on_error must be 'raise', "
                            f"got {options.on_error!r}; TactileStream skips samples it cannot read")
    return options


# ItemOptions' fields: the keywords the torch datasets took before `options=` (deprecated there)
FIELDS = tuple(f.name for f in dataclasses.fields(ItemOptions))


def item_options(options: ItemOptions | None) -> ItemOptions:
    """The options a dataset reads: `options`, or the defaults when None.

    Args:
        options: the object passed as `options=` (None: none).

    Returns:
        An ItemOptions.

    Raises:
        ArgumentError: `options` is neither None nor an ItemOptions.
    """
    if options is None:
        return ItemOptions()
    if not isinstance(options, ItemOptions):
        raise ArgumentError(f"options must be an htdata.read.itemoptions.ItemOptions, got {type(options).__name__}")
    return options


def keywords_as_options(options: ItemOptions | None, keywords: dict) -> ItemOptions:
    """A dataset's old keywords (deprecated: htdata/_moved.py `folded_keywords`) as its ItemOptions.

    Args:
        options: the object the call also passed as `options=` (None: none).
        keywords: the ItemOptions fields the call gave as keywords.

    Returns:
        ItemOptions(**keywords).

    Raises:
        ArgumentError: both `options=` and keywords were given.
    """
    if options is not None:
        given = ", ".join(sorted(keywords))
        raise ArgumentError(f"pass either options= or its keywords, not both (also given: {given}); "
                            f"options.replace({sorted(keywords)[0]}=...) changes one")
    return ItemOptions(**keywords)
