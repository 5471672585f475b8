"""A pipeline's normalisation settings, apart from the rest of the pipeline: the `[normalise.<layout>]`
tables over each layout's value block, and the rule that every table names a layout in use.

The ingest builds them from its pipeline (htdata/ingest/pipeline.py `normalise_settings`, one object per
pipeline state); `htdata renormalise` needs nothing else of a pipeline, so curation reads these without
importing ingest's configuration. A settings object resolves each layout once (`normalise_for`: the table
over the value block, the calibration file found and hashed, the result checked) and every later call for
that layout reads the resolved config: the ingest's episodes and renormalise's plan, warnings and rewrite
share one NormaliseConfig per layout, never one each.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from htdata.errors import ConfigError
from htdata.glove.glovevalue import is_raw_count
from htdata.glove.layouts import nearest_hint
from htdata.glove.normaliseconfig import NOISE_K_BASELINES, RAW_COUNT_DEFAULTS, NormaliseConfig

GLOVE_REST_KEYS = ("baseline", "noise_k", "taxel_calibration")   # the keys a pooled glove rest's table sets


def glove_rest_config(path: str | Path) -> NormaliseConfig:
    """The `[normalise.<id>]` table of a glove's pooled rest (htdata.glove.pooledrest): baseline "shift" on the
    reference file at `path`, the raw-count default's noise_k (it sets GLOVE_REST_KEYS).

    Args:
        path: the pooled rest's reference file (a taxel calibration).

    Returns:
        The table, not yet laid over a layout's value block (`NormaliseSettings.normalise_for` does that).
    """
    return NormaliseConfig(baseline="shift", noise_k=float(RAW_COUNT_DEFAULTS["noise_k"]), taxel_calibration=str(path))


@dataclass(frozen=True)
class NormaliseSettings:
    """A pipeline's normalisation settings; `normalise_for(layout)` gives one glove's NormaliseConfig.

    Args:
        name: the pipeline's name (named in calibration origins and errors).
        path: the pipeline file it came from ("" when built in code); relative calibration files resolve beside it.
        normalise: layout id -> its `[normalise.<id>]` table.
        normalise_given: layout id -> the keys that table sets (the rest come from the layout's value block).
        layouts: hand -> layout id or layout JSON path (the pipeline's `[layouts]`).
        shared_layouts: layout ids meant for other sources, exempt from `check_layout_names`.
        settings: the `--set` items applied, to name them in errors.
        fit_frames: frames a fixed baseline is fitted on (the first chunk of an episode: `[tactile] chunk_frames`).
    """
    name: str
    path: str = ""
    normalise: dict[str, NormaliseConfig] = field(default_factory=dict)
    normalise_given: dict[str, tuple[str, ...]] = field(default_factory=dict)
    layouts: dict[str, str] = field(default_factory=dict)
    shared_layouts: list[str] = field(default_factory=list)
    settings: tuple[str, ...] = ()
    fit_frames: int = 64   # [tactile] chunk_frames' default
    # (layout id, its value block) -> the resolved config (normalise_for); a new object starts empty
    _resolved: dict[tuple[str, str], NormaliseConfig] = field(default_factory=dict, init=False, repr=False,
                                                              compare=False)

    def default_note(self, layout) -> str | None:
        """One line when `layout` holds raw counts and has no `[normalise.<id>]` table, so the raw-count default
        (RAW_COUNT_DEFAULTS) applies to it (None otherwise): the ingest says once per layout what it chose.

        Args:
            layout: a glove.layouts.Layout in use.

        Returns:
            The note, or None.
        """
        if layout.layout_id in self.normalise:
            return None
        value = layout.value
        if not is_raw_count(value["max"]):
            return None
        d = RAW_COUNT_DEFAULTS
        return (f"layout {layout.layout_id} holds raw counts (value.max {float(value['max']):g}) and pipeline "
                f"{self.name!r} has no [normalise.{layout.layout_id}] table: the raw-count default applies, "
                f"baseline = \"{d['baseline']}\" (each cell's {d['baseline_percentile']:g}th percentile per "
                f"{d['drift_window_s']:g} s window), noise_k = {d['noise_k']:g} (a per-cell floor): each cell's rest "
                f"from its own recording, as fewer than 3 of the glove's recordings are pooled (docs/INGEST.md "
                f"\"The glove's own rest\")")

    def with_glove_rests(self, references: dict[str, Path]) -> "NormaliseSettings":
        """A copy with the pooled glove rest's table (`glove_rest_config`) for each layout id in `references`.

        Args:
            references: layout id -> its pooled rest's reference file.

        Returns:
            The new settings.

        Raises:
            ConfigError: a layout in `references` has its own `[normalise.<id>]` table (add_glove_rests).
        """
        normalise, given = add_glove_rests(self.normalise, self.normalise_given, references, self.path or self.name)
        return dataclasses.replace(self, normalise=normalise, normalise_given=given)

    def normalise_for(self, layout) -> NormaliseConfig:
        """The config for `layout`: its `[normalise.<id>]` table over its value block.

        Args:
            layout: a glove.layouts.Layout.

        Returns:
            The checked NormaliseConfig (a taxel calibration file resolved, its sha256 filled in): the same object
            for every call with this layout (resolved at the first), so callers read it and never change it.

        Raises:
            ConfigError: the taxel calibration file is not found, or the config is invalid (NormaliseConfig.validate).
        """
        key = (layout.layout_id, json.dumps(layout.value, sort_keys=True, default=str))
        if key not in self._resolved:
            self._resolved[key] = self._resolve(layout)
        return self._resolved[key]

    def _resolve(self, layout) -> NormaliseConfig:
        """`normalise_for`'s work, done once per layout (its docstring)."""
        base = NormaliseConfig.from_layout_value(layout.value)
        if layout.layout_id not in self.normalise:
            return base
        cfg = self.normalise[layout.layout_id]
        given = self.normalise_given.get(layout.layout_id, tuple(cfg.to_dict()))
        out = dataclasses.replace(base, **{k: getattr(cfg, k) for k in given})
        if "noise_k" not in given and out.baseline not in NOISE_K_BASELINES:
            out = dataclasses.replace(out, noise_k=0.0)    # a raw-count default floor, under a baseline without one
        if out.taxel_calibration:
            out = self._taxel_calibration(out)
        return out.validate()

    def _taxel_calibration(self, cfg: NormaliseConfig) -> NormaliseConfig:
        """Resolve the calibration file (relative to the pipeline file, else the working folder) + its sha256."""
        p = Path(cfg.taxel_calibration)
        if not p.is_absolute() and self.path and (Path(self.path).parent / p).is_file():
            p = Path(self.path).parent / p
        if not p.is_file():
            raise ConfigError(f"{self.path or self.name}: taxel_calibration file {cfg.taxel_calibration!r} not "
                              f"found (relative to the pipeline file or the working folder)")
        return dataclasses.replace(cfg, taxel_calibration=str(p.resolve()),
                                   taxel_calibration_sha256=hashlib.sha256(p.read_bytes()).hexdigest())

    def check_layout_names(self, used_ids: set[str], used_hands: set[str] | None, scope: str,
                           why: str = "") -> None:
        """Refuse layout ids these settings name that no recording of `scope` uses.

        A `[normalise.<id>]` table (from the file or `--set normalise.<id>.*`) whose id no recording uses,
        or a `[layouts]` entry for a hand no recording has (`used_hands`; None skips that check), is an
        error naming the ids in use and the nearest one: a typo would otherwise leave the glove on its
        layout's defaults without a word. Ids in `shared_layouts` are exempt.

        Args:
            used_ids: the layout ids the recordings of `scope` use.
            used_hands: the hands they have (None: not checked).
            scope: what was planned, named in the message ("source DIR", "dataset DIR version N").
            why: appended to the message (e.g. the recordings that could not be planned).

        Raises:
            ConfigError: a table or `[layouts]` entry names nothing in use (all of them, one message).
        """
        shared = set(self.shared_layouts)
        problems = []
        if used_hands is not None:
            for hand, name in sorted(self.layouts.items()):
                lid = Path(name).stem if name.endswith(".json") else name
                if hand not in used_hands and lid not in shared:
                    problems.append(f"[layouts] {hand} = {name!r}: no recording of {scope} has a {hand} hand "
                                    f"(hands in use: {', '.join(sorted(used_hands)) or 'none'})")
        in_use = ", ".join(sorted(used_ids)) or "none"
        for lid in sorted(self.normalise):
            if lid in used_ids or lid in shared:
                continue
            given = [s for s in self.settings if s.partition("=")[0].startswith(f"normalise.{lid}.")]
            how = f"--set {given[0]}" if given else f"[normalise.{lid}]"
            problems.append(f"{how} names layout {lid!r}, which no recording of {scope} uses (layouts in use: "
                            f"{in_use}{nearest_hint(lid, used_ids)})")
        if problems:
            raise ConfigError(f"{self.path or self.name}: {'; '.join(problems)}. Fix the id, or list it in the "
                              f"pipeline's shared_layouts = [...] when it is meant for other sources{why}")


def add_glove_rests(normalise: dict, given: dict, references: dict[str, Path], where: str) -> tuple[dict, dict]:
    """(normalise, normalise_given) with the pooled glove rest's table for each layout id in `references`; a layout
    whose table the pipeline sets is refused (its rest is the table's).

    Args:
        normalise: layout id -> NormaliseConfig, the pipeline's tables.
        given: layout id -> the keys each table sets.
        references: layout id -> its pooled rest's reference file.
        where: the pipeline, named in the error.

    Returns:
        New (normalise, given) dicts; the arguments are not changed.

    Raises:
        ConfigError: a layout in `references` has its own table.
    """
    normalise, given = dict(normalise), dict(given)
    for lid, path in references.items():
        if lid in normalise:
            raise ConfigError(f"{where}: layout {lid} has a [normalise.{lid}] table: its rest is the table's, "
                              f"not a pooled one")
        normalise[lid], given[lid] = glove_rest_config(path), GLOVE_REST_KEYS
    return normalise, given
