import cv2
import numpy as np
import pytest

from htdata.source.rgb import centre_square, to_rgb, to_square_224


@pytest.mark.parametrize("h,w", [(480, 640), (640, 480), (1, 1), (223, 225), (7, 3), (1080, 1920), (224, 224)])
def test_known_colour_survives_any_shape(h, w):
    frame = np.empty((h, w, 3), dtype=np.uint8)
    frame[:] = (200, 30, 90)
    out = to_square_224(frame)
    assert out.shape == (224, 224, 3) and out.dtype == np.uint8 and out.flags.c_contiguous
    assert np.all(out == (200, 30, 90))


def test_centre_crop_discards_side_bands():
    frame = np.zeros((480, 640, 3), dtype=np.uint8)
    frame[:, :80] = 255      # left band outside the centred 480x480 square
    frame[:, -80:] = 255     # right band
    frame[:, 80:-80] = (10, 20, 30)
    out = to_square_224(frame)
    assert np.all(out == (10, 20, 30))


def test_crop_none_squashes_whole_frame():
    frame = np.zeros((480, 640, 3), dtype=np.uint8)
    frame[:, :320] = 255
    out = to_square_224(frame, crop="none")
    assert np.all(out[:, :100] == 255) and np.all(out[:, 124:] == 0)


def test_matches_cv2_area_on_the_cropped_square():
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, size=(481, 641, 3), dtype=np.uint8)
    sq = frame[0:481, 80:561]
    np.testing.assert_array_equal(centre_square(frame), sq)
    expected = cv2.resize(np.ascontiguousarray(sq), (224, 224), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(to_square_224(frame), expected)


def test_other_size_and_interpolation():
    frame = np.full((100, 50, 3), 7, dtype=np.uint8)
    assert to_square_224(frame, size=32, interpolation="linear").shape == (32, 32, 3)


def test_channel_order():
    frame = np.zeros((2, 2, 3), dtype=np.uint8)
    frame[..., 0] = 1
    frame[..., 2] = 3
    assert to_rgb(frame, "bgr")[0, 0].tolist() == [3, 0, 1]
    assert to_rgb(frame, "rgb") is frame
    with pytest.raises(ValueError, match="channel_order"):
        to_rgb(frame, "rbg")


@pytest.mark.parametrize("bad", [np.zeros((4, 4), np.uint8), np.zeros((4, 4, 4), np.uint8),
                                 np.zeros((4, 4, 3), np.float32), np.zeros((0, 4, 3), np.uint8)])
def test_bad_frames_rejected(bad):
    with pytest.raises(ValueError, match="frame 3: expected"):
        to_square_224(bad, where="frame 3")


@pytest.mark.parametrize("kwargs", [{"crop": "top"}, {"interpolation": "lanczos9"}, {"size": 0}])
def test_bad_options_rejected(kwargs):
    with pytest.raises(ValueError):
        to_square_224(np.zeros((4, 4, 3), np.uint8), **kwargs)


def test_cubic2x_area_is_cubic_to_twice_the_target_then_the_2x2_box():
    # issue #47's opt-in resize: the default stays INTER_AREA (RGB bytes of a default ingest unchanged)
    rng = np.random.default_rng(3)
    frame = cv2.GaussianBlur(rng.integers(0, 256, (480, 640, 3), dtype=np.uint8), (0, 0), 1.5)
    sq = np.ascontiguousarray(frame[:, 80:560])
    big = cv2.resize(sq, (448, 448), interpolation=cv2.INTER_CUBIC)
    expected = cv2.resize(big, (224, 224), interpolation=cv2.INTER_AREA)
    out = to_square_224(frame, interpolation="cubic2x_area")
    assert out.shape == (224, 224, 3) and out.flags["C_CONTIGUOUS"]
    np.testing.assert_array_equal(out, expected)
    assert np.abs(out.astype(int) - to_square_224(frame).astype(int)).mean() < 1.0


@pytest.mark.parametrize("side", [224, 300, 447])
def test_cubic2x_area_is_plain_area_under_twice_the_target(side):
    rng = np.random.default_rng(side)
    frame = rng.integers(0, 256, (side, side, 3), dtype=np.uint8)
    np.testing.assert_array_equal(to_square_224(frame, interpolation="cubic2x_area"), to_square_224(frame))


def test_the_default_interpolation_is_still_area():
    from htdata.source.rgbsettings import RgbConfig

    assert RgbConfig().interpolation == "area"


def test_the_schema_allows_exactly_the_interpolations():
    import json
    from pathlib import Path

    from htdata.resources import SCHEMAS_DIR
    from htdata.source.rgb import INTERPOLATIONS

    schema = json.loads((Path(SCHEMAS_DIR) / "pipeline.schema.json").read_text())
    assert schema["properties"]["rgb"]["properties"]["interpolation"]["enum"] == list(INTERPOLATIONS)
