"""A pipeline's `[codec]` section: the EXR pixel type of the tactile maps, as set and as resolved for a run
by the rule in htdata/glove/codecrule.py, apart from the rest of the pipeline.

An ingest pipeline (htdata/ingest/pipeline.py) holds one as its `codec`; the compression is the
`[tactile]` section's (htdata/format/tactilesettings.py). Keys are checked by
schemas/pipeline.schema.json (`[codec]`).

    [codec]
    tactile = "auto"          # "auto" (the rule's pick for the dataset's gloves) | "exr_half" | "exr_float"
    # choice = {...}          # written by the ingest when it resolves the setting, never by hand
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from htdata.glove.codecrule import CodecChoice, GloveStep, resolve_codec


@dataclass
class CodecConfig:
    """[codec]: tactile = "auto" (default: the EXR pixel type the rule in htdata/glove/codecrule.py picks for the
    dataset's gloves) or an explicit "exr_half" / "exr_float"; the compression is [tactile] compression.

    `choice` is not written by hand: the ingest fills it in when it resolves the setting for a run
    (`with_choice`), so workers and the manifest see one resolved codec.
    """
    tactile: str = "auto"
    choice: dict | None = None       # htdata.glove.codecrule.CodecChoice.info()

    @classmethod
    def from_dict(cls, data: dict) -> "CodecConfig":
        """[codec] as written (TOML / to_dict)."""
        return cls(**data)

    def to_dict(self) -> dict:
        return {"tactile": self.tactile, **({"choice": dict(self.choice)} if self.choice else {})}

    def resolve(self, compression: str, gloves: list[GloveStep], existing: dict | None = None) -> CodecChoice:
        """The codec this setting gives a dataset with `gloves` at `compression` (codecrule.resolve_codec)."""
        return resolve_codec(self.tactile, compression, gloves, existing)

    def with_choice(self, choice: CodecChoice, compression: str, where: str) -> "CodecConfig":
        """A copy carrying `choice`, which must be for `compression` (the pipeline's [tactile] compression)."""
        if choice.compression != compression:
            raise ValueError(f"{where}: codec choice {choice.codec} does not match "
                              f"[tactile] compression {compression!r}")
        return dataclasses.replace(self, choice=choice.info())

    def resolved(self, where: str) -> CodecChoice:
        """The resolved tactile codec; ValueError before the ingest resolved it (`with_choice`)."""
        if self.choice is None:
            raise ValueError(f"{where}: [codec] tactile = {self.tactile!r} is not resolved for a dataset yet "
                             f"(the ingest resolves it per run: htdata.ingest.plan.resolve_sources)")
        return CodecChoice.from_info(self.choice)
