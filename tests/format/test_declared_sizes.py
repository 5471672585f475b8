"""Issue 35 items 4 and 5: image sizes come from the header, checked before a decoder allocates them.

A 691-byte JPEG declaring 30000x30000 cost ~5 GB; an EXR member with a 20000x20000 data window 2.3 GB;
a 200000-pixel display window a MemoryError and a validate traceback. Now each is refused from its
header: a DatasetError naming the member, nothing decoded (the peak RSS of a process reading them
stays that of a process reading nothing).
"""

from __future__ import annotations

import numpy as np
import pytest

from htdata.errors import DatasetError
from htdata.format.codec import decode_rgb, encode_rgb
from htdata.format.imageheader import DeclaredShapeError, exr_windows, jpeg_size
from htdata.format.tactilecodec import decode_exr_pixels, decode_tactile, encode_exr, encode_tactile
from tests.factories.hostile import forged_exr, forged_jpeg, peak_rss_mb


def test_headers_give_the_sizes_our_encoders_write():
    assert jpeg_size(encode_rgb(np.zeros((224, 224, 3), np.uint8))) == (224, 224)
    m = np.zeros((224, 224), np.float32)
    m[10:20, 30:50] = 0.5
    assert exr_windows(encode_tactile(m)) == ((0, 0, 223, 223), (0, 0, 223, 223))
    assert exr_windows(encode_exr(m, window=True)) == ((30, 10, 49, 19), (0, 0, 223, 223))
    for junk in (b"", b"\xff\xd8", b"not a jpeg", forged_jpeg(8, 8)[:20]):
        assert jpeg_size(junk) is None
    assert exr_windows(b"\x76\x2f\x31\x01\x02\0\0\0" + b"x" * 40) is None


def test_a_jpeg_member_declaring_another_size_is_refused_undecoded():
    with pytest.raises(DeclaredShapeError, match=r"ep_a__000003.rgb.jpg: JPEG declares 30000x30000 pixels, "
                                                 r"expected 224x224: not decoded") as info:
        decode_rgb(forged_jpeg(30000, 30000), "ep_a__000003.rgb.jpg")
    assert info.value.found == (30000, 30000)
    with pytest.raises(DeclaredShapeError, match="JPEG declares 8x8 pixels"):
        decode_rgb(forged_jpeg(8, 8), "x")      # a small wrong size too: the member is 224x224 or refused
    with pytest.raises(DatasetError, match="not a decodable JPEG"):
        decode_rgb(b"\xff\xd8\xff\xd9", "x")


@pytest.mark.parametrize("data_window,display_window,said", [
    (((0, 0), (19999, 19999)), ((0, 0), (19999, 19999)), "is 20000x20000, expected 224x224: not decoded"),
    (((0, 0), (19999, 19999)), ((0, 0), (223, 223)), "data window (0, 0, 19999, 19999) is not inside"),
    (((0, 0), (0, 0)), ((0, 0), (199999, 0)), "is 1x200000, expected 224x224"),
])
def test_an_exr_member_with_forged_windows_is_refused_before_its_pixels(data_window, display_window, said):
    data = forged_exr(data_window, display_window)
    assert len(data) < 1000
    for decode in (decode_tactile, decode_exr_pixels):
        with pytest.raises(DatasetError) as info:
            decode(data, "ep_a__000001.tactile_right.exr")
        assert str(info.value).startswith("ep_a__000001.tactile_right.exr: EXR ") and said in str(info.value)


def test_refusing_forged_headers_allocates_nothing():
    """In a fresh process: every forged member refused; its peak RSS stays far below one decoded forgery
    (a 20000x20000 half window alone is 800 MB, a 30000x30000 RGB frame 2.7 GB)."""
    code = """
from htdata.errors import DatasetError
from htdata.format.codec import decode_rgb, decode_tactile
from tests.factories.hostile import forged_exr, forged_jpeg
members = [(decode_rgb, forged_jpeg(30000, 30000)),
           (decode_tactile, forged_exr(((0, 0), (19999, 19999)), ((0, 0), (19999, 19999)))),
           (decode_tactile, forged_exr(((0, 0), (0, 0)), ((0, 0), (199999, 199999))))]
for decode, data in members:
    try:
        decode(data, "m")
    except DatasetError as exc:
        print("refused", exc)
"""
    out, peak = peak_rss_mb(code)
    assert out.count("refused m: ") == 3, out
    assert peak < 400, peak
