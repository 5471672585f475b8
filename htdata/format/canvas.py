"""The canonical canvas and the hand names: the constants every member of a sample is shaped by."""

CANVAS = 224                       # canonical map and RGB frame side, pixels
MAP_SHAPE = (CANVAS, CANVAS)
HANDS = ("left", "right")          # fixed order: left before right everywhere
