"""Adapter params: each adapter declares once (its `PARAMS`) what `[adapter.params]` may hold.

`check_declared_params` checks a pipeline's params against one adapter's declaration; the
pipeline's own check (htdata.ingest.pipeline.check_adapter_params) finds the adapter by name first.
"""

from __future__ import annotations

from dataclasses import dataclass

from htdata.errors import ConfigError


@dataclass(frozen=True)
class AdapterParam:
    """One `[adapter.params]` key an adapter understands."""
    name: str
    types: tuple[type, ...]   # accepted TOML value types (bool is never taken for int)
    default: object
    help: str


def param_values(declared: tuple[AdapterParam, ...], params: dict) -> dict:
    """Every declared param: its value in `params`, else its default (declared once, in PARAMS)."""
    return {**{p.name: p.default for p in declared}, **params}


def check_declared_params(adapter: str, declared: tuple[AdapterParam, ...], params: dict, where: str) -> None:
    """Raise ConfigError naming the key and listing the known params when `params` does not fit `declared`."""
    known = {p.name: p for p in declared}
    listing = ", ".join(f"{p.name} ({'/'.join(t.__name__ for t in p.types)}, default {p.default!r})"
                        for p in declared) or "none"
    for key, value in params.items():
        if key not in known:
            raise ConfigError(f"{where}: adapter.params.{key} is not a param of adapter {adapter!r}; "
                              f"known params: {listing}")
        spec = known[key]
        ok = isinstance(value, spec.types) and not (isinstance(value, bool) and bool not in spec.types)
        if not ok:
            raise ConfigError(f"{where}: adapter.params.{key} must be {'/'.join(t.__name__ for t in spec.types)} "
                              f"({spec.help}), got {type(value).__name__} {value!r}")
