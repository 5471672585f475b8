"""Our tactile EXR members are standard EXR: OpenImageIO, an independent reader, agrees.

htdata writes and reads EXR through the OpenEXR Python binding only; these
tests keep the stored maps readable by the imaging ecosystem (OIIO backs
oiiotool, Blender, Nuke): single channel "Y", HALF, ZIP, 224x224, and the
same float16 bits. The reverse direction proves our decoder reads an EXR
that another writer made. OIIO traps (TOOLING_FACTS): `read_image` returns
float32 unless asked for "half"; writers must get (H,W,C), never (H,W).
"""

from __future__ import annotations

import io

import numpy as np
import OpenEXR
import pytest

from htdata.format.canvas import MAP_SHAPE
from htdata.format.tactilecodec import decode_tactile, encode_tactile

oiio = pytest.importorskip("OpenImageIO")


def _maps() -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    sparse = np.zeros(MAP_SHAPE, np.float32)
    sparse[40:90, 100:130] = rng.random((50, 30), dtype=np.float32)
    edges = np.zeros(MAP_SHAPE, np.float32)
    edges[0, :4] = [1.0, 1.0 - 2.0**-11, 2.0**-24, 2.0**-14]   # exact top, spacing below 1, subnormals
    return [sparse, edges, rng.random(MAP_SHAPE, dtype=np.float32)]


def _oiio_read(path) -> tuple[object, np.ndarray]:
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, "half")
        assert pixels is not None, inp.geterror()
    finally:
        inp.close()
    return spec, np.asarray(pixels)


@pytest.mark.parametrize("which", range(3))
def test_oiio_reads_our_tactile_member(tmp_path, which):
    tactile = _maps()[which]
    path = tmp_path / "tactile.exr"
    path.write_bytes(encode_tactile(tactile, where=f"map {which}"))
    spec, pixels = _oiio_read(path)
    assert (spec.width, spec.height, spec.nchannels) == (MAP_SHAPE[1], MAP_SHAPE[0], 1)
    assert list(spec.channelnames) == ["Y"]
    assert spec.format == oiio.TypeDesc("half")
    assert spec.getattribute("compression") == "zip"
    assert pixels.shape == (*MAP_SHAPE, 1) and pixels.dtype == np.float16
    ours = decode_tactile(path.read_bytes(), where=str(path))
    np.testing.assert_array_equal(pixels[..., 0].view(np.uint16), ours.astype(np.float16).view(np.uint16))
    assert np.abs(ours - tactile).max() <= 2.0**-12     # half round-off on [0,1]


def test_our_decoder_reads_an_oiio_written_exr(tmp_path):
    tactile = _maps()[0]
    path = tmp_path / "oiio.exr"
    spec = oiio.ImageSpec(MAP_SHAPE[1], MAP_SHAPE[0], 1, "half")
    spec.channelnames = ("Y",)
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(str(path))
    assert out is not None, oiio.geterror()
    assert out.open(str(path), spec), out.geterror()
    assert out.write_image(tactile.astype(np.float16)[..., None]), out.geterror()   # (H,W,C): see module doc
    out.close()
    ours = decode_tactile(path.read_bytes(), where=str(path))
    np.testing.assert_array_equal(ours, tactile.astype(np.float16).astype(np.float32))


@pytest.mark.parametrize("pixel_type", [np.float16, np.float32])
@pytest.mark.parametrize("which", ["sparse", "empty", "corner"])
def test_a_data_window_reads_back_as_the_full_canvas_everywhere(tmp_path, pixel_type, which):
    """A map stored with only its covered pixels' data window (display window 224x224): OpenEXR placed by
    dataWindow, OpenImageIO's display-window read and our decoder all give the whole canvas back."""
    from htdata.format.tactilecodec import covered_window, encode_exr

    tactile = {"sparse": _maps()[0], "empty": np.zeros(MAP_SHAPE, np.float32),
               "corner": np.pad(np.full((3, 5), 0.75, np.float32), ((221, 0), (0, 219)))}[which]
    data = encode_exr(tactile, "zip", pixel_type, window=True)
    assert len(data) < len(encode_exr(tactile, "zip", pixel_type)) or which == "empty"
    want = tactile.astype(pixel_type).astype(np.float32)
    f = OpenEXR.File(io.BytesIO(data))
    (x0, y0), (x1, y1) = (tuple(int(v) for v in c) for c in f.header()["dataWindow"])
    assert (x0, y0, x1, y1) == covered_window(tactile)
    assert [list(map(int, c)) for c in f.header()["displayWindow"]] == [[0, 0], [223, 223]]
    canvas = np.zeros(MAP_SHAPE, np.float32)
    canvas[y0:y1 + 1, x0:x1 + 1] = f.channels()["Y"].pixels
    np.testing.assert_array_equal(canvas, want)
    path = tmp_path / "w.exr"
    path.write_bytes(data)
    buf = oiio.ImageBuf(str(path))
    assert (buf.spec().full_width, buf.spec().full_height) == (224, 224)
    pixels = np.asarray(buf.get_pixels(oiio.FLOAT, oiio.ROI(0, 224, 0, 224, 0, 1, 0, 1)))[..., 0]
    np.testing.assert_array_equal(pixels, want)
    np.testing.assert_array_equal(decode_tactile(data, "w.exr"), want)


def test_a_data_window_outside_the_display_window_is_refused():
    buf = io.BytesIO()
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "dataWindow": ((200, 200), (239, 239)), "displayWindow": ((0, 0), (223, 223))},
             {"Y": np.zeros((40, 40), np.float16)}).write(buf)
    with pytest.raises(ValueError, match="data window .* not inside its display window"):
        decode_tactile(buf.getvalue(), "odd.exr")
