"""htdata: full-hand tactile + egocentric RGB dataset toolkit.

Data path: adapters (read a source) -> sync (pair clocks) -> normalise (glove
units to [0,1]) -> rasterise (taxels to the canonical 224x224 map) -> codec
(EXR/JPEG) -> shards + index -> reader / torchdata -> handtouch trainer.
"""

__version__ = "0.1.0"
