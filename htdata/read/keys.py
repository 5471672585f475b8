"""Keys of the items the torch datasets yield (and of the batches a DataLoader makes of them).

One place for the names, as LeRobot's `utils/constants.py` does: the trainer,
the benchmark and the datasets all spell a key through these constants, so a
renamed key is one edit. Shapes are those of `htdata.read.torchdata` (frame items;
window items stack TACTILE, RGB, FRAME and INDEX over the window).
"""

TACTILE = "tactile"      # (1,224,224) float32 map in [0,1]
COVERAGE = "coverage"    # (1,224,224) float32 0/1: where the item's glove has sensors
REGIONS = "regions"      # (224,224) uint8 part ids (thumb=1 .. palm=6, 0 outside the hand)
RGB = "rgb"              # (3,224,224) uint8 (float32 in [0,1] with rgb_float=True)
HAND = "hand"            # int64: 0 left, 1 right (HAND_IDS)
TASK = "task"            # int64: position in manifest["tasks"]
SCENE = "scene"          # int64: position in manifest["scenes"]
EPISODE = "episode"      # int64: position in episodes.jsonl
FRAME = "frame"          # int64: frame index within the episode
INDEX = "index"          # int64: global sample index
T_NS = "t_ns"            # (window,) int64 recorded glove timestamps (htdata.read.torchglove windows)
HAS_RGB = "has_rgb"      # bool: the item's RGB is real (frames="tactile" items of glove-only samples: zeros)
LAYOUT = "layout"        # int64: position of the item's glove layout in ItemConstants.layouts
IDS = "ids"              # (8,) int64, constants="once" items: the ids below packed in one tensor
ID_FIELDS = (HAND, TASK, SCENE, EPISODE, FRAME, INDEX, HAS_RGB, LAYOUT)

HAND_IDS = {"left": 0, "right": 1}
