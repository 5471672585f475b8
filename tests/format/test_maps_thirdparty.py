"""A default-ingested dataset read the way a stranger reads it: `tarfile` + OpenEXR (or OpenImageIO), no htdata.

The format promises 224x224 tactile maps in the shards (issue 26 item 1): a new dataset stores them by
default. For every sample and hand, the `tactile_<hand>.exr` member a plain reader finds must be the map
`htdata.open(...)` serves, bit for bit (the member's half or float pixels widened to float32). The stranger
places pixels by the file's dataWindow inside its displayWindow, as the EXR standard says: a writer may
store only the window that holds the covered pixels.
"""

from __future__ import annotations

import io
import tarfile
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

import htdata
from tests.factories import ingest_cli, make_native, make_opentouch, make_touchanything


@pytest.fixture(scope="module")
def default_dataset(tmp_path_factory) -> Path:
    """All three source formats (TouchAnything has both hands), ingested with no --set at all."""
    tmp = tmp_path_factory.mktemp("thirdparty")
    sources = {"opentouch": make_opentouch(tmp / "ot"), "touchanything": make_touchanything(tmp / "ta"),
               "native": make_native(tmp / "nat")}
    out = tmp / "ds"
    assert ingest_cli(*[a for name, src in sources.items() for a in ("--pipeline", f"{name}={src}")], out) == 0
    return out


def _members(root: Path) -> dict[str, dict[str, bytes]]:
    """key -> {member suffix: bytes} of every shard tar under the dataset, as a webdataset reader groups them."""
    samples: dict[str, dict[str, bytes]] = {}
    for shard in sorted((root / "shards").rglob("*.tar")):
        with tarfile.open(shard) as tar:
            for info in tar:
                if info.isfile():
                    key, suffix = info.name.split(".", 1)
                    samples.setdefault(key, {})[suffix] = tar.extractfile(info).read()
    return samples


def _openexr_canvas(data: bytes) -> np.ndarray:
    f = OpenEXR.File(io.BytesIO(data))
    (dx0, dy0), (dx1, dy1) = (np.asarray(v) for v in f.header()["displayWindow"])
    (x0, y0), (x1, y1) = (np.asarray(v) for v in f.header()["dataWindow"])
    canvas = np.zeros((int(dy1 - dy0 + 1), int(dx1 - dx0 + 1)), np.float32)
    canvas[y0 - dy0:y1 - dy0 + 1, x0 - dx0:x1 - dx0 + 1] = f.channels()["Y"].pixels
    return canvas


def _oiio_canvas(data: bytes, tmp: Path) -> np.ndarray:
    oiio = pytest.importorskip("OpenImageIO")
    path = tmp / "member.exr"
    path.write_bytes(data)
    buf = oiio.ImageBuf(str(path))
    full = buf.spec().full_width, buf.spec().full_height
    # ROI of the display window: pixels outside the data window read as 0
    pixels = buf.get_pixels(oiio.FLOAT, oiio.ROI(0, full[0], 0, full[1], 0, 1, 0, 1))
    assert pixels is not None, buf.geterror()
    return np.asarray(pixels)[..., 0]


@pytest.mark.parametrize("reader", ["openexr", "openimageio"])
def test_a_plain_reader_finds_every_served_map(default_dataset, reader, tmp_path):
    samples = _members(default_dataset)
    ds = htdata.open(default_dataset)
    assert len(samples) == len(ds) > 0
    hands_seen, both = 0, 0
    for i in range(len(ds)):
        served = ds.decoded(i)["tactile"]
        members = samples[ds.key(i)]
        stored = {s[len("tactile_"):-len(".exr")]: b for s, b in members.items() if s.startswith("tactile_")}
        assert sorted(stored) == sorted(served), ds.key(i)
        for hand, data in stored.items():
            canvas = _openexr_canvas(data) if reader == "openexr" else _oiio_canvas(data, tmp_path)
            assert canvas.shape == (224, 224)
            np.testing.assert_array_equal(canvas, served[hand], err_msg=f"{ds.key(i)} {hand}")
            hands_seen += 1
        both += len(stored) == 2
    assert hands_seen > len(ds) // 2 and both > 0      # maps in most samples, both hands in TouchAnything's


def test_the_default_records_stored_maps_beside_the_raw_rows(default_dataset):
    ds = htdata.open(default_dataset)
    assert ds.manifest["codec"]["tactile"]["maps"] == "stored"
    names = {s for m in _members(default_dataset).values() for s in m}
    assert {"tactile_left.exr", "tactile_right.exr", "raw_left.npy", "raw_right.npy"} <= names
