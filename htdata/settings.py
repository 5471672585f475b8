"""`--set [TARGET:]dotted.key=value`: the one parser and the one targeting rule of every override.

Used by `htdata ingest --set`, `htdata renormalise --set`, the benchmarks and
HandTouch's configs (`handtouch.config`), so an override means the same
everywhere:

- the value is read as a TOML literal when it parses (`true`, `20`, `0.5`,
  `["right"]`, `"text"`), else taken as the text itself (`labels.csv`);
  TOML dates and times are taken as text (no setting takes one);
- the key is dotted (`adapter.params.annotations`, `normalise.glove_l.noise_k`);
  every part non-empty; a part that names a value where a table is needed is an error;
- `TARGET:` aims the override at one named config (a pipeline of a
  multi-source ingest); without it, it applies to every config of the command.
"""

from __future__ import annotations

import datetime
import tomllib

from htdata.errors import ConfigError


def parse_setting(item: str) -> tuple[str, object]:
    """"a.b.c=value" -> ("a.b.c", value)."""
    key, sep, text = item.partition("=")
    key = key.strip()
    if not sep or not key or any(not p for p in key.split(".")):
        raise ConfigError(f"--set {item!r}: expected dotted.key=value (e.g. adapter.params.annotations=labels.csv)")
    try:
        value = tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        value = text
    if isinstance(value, (datetime.date, datetime.time)):
        value = text
    return key, value


def apply_settings(data: dict, settings: list[str]) -> dict:
    """`data` (a config as nested dicts) with each setting written in, in order (in place; returned)."""
    for item in settings:
        key, value = parse_setting(item)
        node = data
        parts = key.split(".")
        for part in parts[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"--set {item}: {part!r} is a value, not a table")
            node = child
        node[parts[-1]] = value
    return data


def aim_settings(settings: list[str], targets: list[str]) -> dict[str, list[str]]:
    """target name -> the settings that apply to it: its own (`TARGET:key=value`) after the shared ones.

    A `TARGET:` that names none of `targets` is an error listing them.
    """
    shared: list[str] = []
    aimed: dict[str, list[str]] = {}
    for item in settings:
        key = item.partition("=")[0]
        target, sep, _ = key.partition(":")
        if sep:
            if target not in targets:
                raise ConfigError(f"--set {item}: no pipeline named {target!r} (pipelines: {sorted(targets)})")
            aimed.setdefault(target, []).append(item[len(target) + 1:])
        else:
            shared.append(item)
    return {t: shared + aimed.get(t, []) for t in targets}
