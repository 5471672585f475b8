"""Where a LeRobot export may go: `--force` replaces only a previous export, never what it did not write.

Every export writes the marker OUT/.htdata-export.json; `--force` replaces an
existing OUT only when it is a folder holding that marker, holds no htdata
dataset and is not inside one. An OUT that is a file or a symlink, a folder
without the marker (someone's data), DATASET itself or a folder above or
below it are refused before any work is done, with one line saying why.
"""

from __future__ import annotations

import json
from pathlib import Path

from htdata.errors import HtdataError
from htdata.fileio import write_bytes_atomic
from htdata.format.table import MANIFEST_FILE
from htdata.store.versions import VERSIONS_DIR

MARKER = ".htdata-export.json"


class ExportTargetRefused(HtdataError, ValueError):
    """OUT is not a place the export may write (or --force may replace)."""


def _is_dataset(folder: Path) -> bool:
    # Committed records only: a bare `.work` is also any tool's scratch folder (`htdata bench --out` has one).
    return (folder / MANIFEST_FILE).exists() or (folder / VERSIONS_DIR).is_dir()


def check_out(out: Path, dataset: Path, force: bool) -> None:
    """Refuse an OUT the export must not write or replace (see the module docstring).

    Args:
        out: where the export is to go.
        dataset: the dataset exported (OUT may not be inside it or hold it).
        force: whether a previous export at OUT may be replaced.

    Raises:
        ExportTargetRefused: OUT is a symlink or a file, inside or holding a dataset, or exists without
            the marker of a previous export.
        FileExistsError: OUT exists and `force` is not set.
    """
    if out.is_symlink():
        raise ExportTargetRefused(f"{out}: is a symlink; give the real folder to export into")
    if out.exists() and not out.is_dir():
        raise ExportTargetRefused(f"{out}: is a file, not a folder; the export writes a folder")
    real_out, real_ds = out.resolve(), dataset.resolve()
    if real_out == real_ds or real_ds in real_out.parents:
        raise ExportTargetRefused(f"{out}: the export may not be written inside DATASET (it is read-only)")
    if real_out in real_ds.parents:
        raise ExportTargetRefused(f"{out}: holds DATASET {dataset}; the export never replaces a folder holding it")
    inside = next((p for p in real_out.parents if _is_dataset(p)), None)
    if inside is not None:
        raise ExportTargetRefused(f"{out}: is inside the htdata dataset {inside}; export somewhere else")
    if not out.exists():
        return
    if not (out / MARKER).is_file():   # said first: --force would not help here
        raise ExportTargetRefused(f"{out}: exists and is not a previous htdata export (no {MARKER}); the export "
                                  f"writes a new folder: choose another OUT (--force replaces only an export it wrote)")
    if not force:
        raise FileExistsError(f"{out} holds a previous htdata export; pass --force to replace it")
    held = next((p.parent for p in out.rglob(MANIFEST_FILE) if _is_dataset(p.parent)), None)
    if held is not None or _is_dataset(out):
        raise ExportTargetRefused(f"{out}: holds an htdata dataset ({held or out}); --force never deletes one")


def write_marker(work: Path, cfg) -> None:
    """The marker that lets a later `--force` recognise this folder as an export it wrote.

    Args:
        work: the export's work folder (moved to OUT when the export is complete).
        cfg: the export's settings (the dataset and version are recorded).
    """
    doc = {"written_by": "htdata export lerobot", "dataset": str(cfg.dataset), "version": cfg.version}
    write_bytes_atomic(work / MARKER, (json.dumps(doc) + "\n").encode())
