"""Damaged and hostile source files (issue #11 item 4): refused or failed with file/episode/frame named.

Damaged H.264 (3000 x 0xFF inside a packet, random bytes in one packet), headers declaring more data
than the file holds (npz member, standalone .npy, HDF5 dataset), a FIFO named chest.mp4, symlinks
leaving the source tree (files and directories) and directory symlinks inside it (followed).
Every case: the bad episode fails, the others are ingested, nothing hangs or allocates GBs.
"""

from __future__ import annotations

import io
import json
import os
import signal
import zipfile
from contextlib import contextmanager
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from htdata.glove.layouts import load_layout
from htdata.source.adapters import get_adapter
from htdata.source.adapters.npzrows import NpzRowError, NpzRows, check_npy_file
from htdata.source.adapters.video import VideoError, iter_video_rgb
from htdata.store.manifest import load_episodes
from htdata.synthetic.formats import TouchAnythingEpisode, write_touchanything_episode
from tests.factories import ingest_cli, make_native, make_opentouch, make_touchanything


@contextmanager
def deadline(seconds: int):
    """Fail (instead of hanging the suite) when the body blocks, e.g. opening a FIFO."""
    def boom(*_):
        raise TimeoutError(f"blocked for more than {seconds} s")
    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def report_of(out: Path) -> dict:
    return json.loads((out / "reports" / "ingest.json").read_text())


def npy_header(shape, dtype="<i8") -> bytes:
    from numpy.lib import format as npy

    buf = io.BytesIO()
    npy.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buf.getvalue()


# --------------------------------------------------------------------------- declared sizes

def test_npz_member_declaring_2e8_timestamps_is_refused_before_allocating(tmp_path):
    path = tmp_path / "tactile_right.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("timestamps_ns.npy", npy_header((200_000_000,)) + np.arange(17_000, dtype=np.int64).tobytes())
    assert path.stat().st_size < 200_000
    with pytest.raises(NpzRowError, match=r"declares shape \(200000000,\) int64 \(1600000000 bytes\) but the "
                                          r"member holds 136000 bytes"):
        NpzRows(path, "timestamps_ns")


def test_npz_entry_claiming_more_than_deflate_can_expand_is_refused(tmp_path):
    path = tmp_path / "x.npz"
    np.savez_compressed(path, values=np.zeros((4, 16, 16), np.float32))
    data = bytearray(path.read_bytes())
    # forge the central directory's uncompressed size (offset 24 in the entry) to 4 GB - 1
    cd = data.rfind(b"PK\x01\x02")
    data[cd + 24:cd + 28] = (0xFFFFFFF0).to_bytes(4, "little")
    path.write_bytes(bytes(data))
    with pytest.raises(NpzRowError, match="more than the data can expand to"):
        NpzRows(path, "values")


def test_native_forged_timestamps_npz_fails_its_episode_only(tmp_path, capsys):
    raw = make_native(tmp_path / "raw")
    bad = raw / "rec_bad"
    import shutil

    shutil.copytree(raw / "rec_good", bad)
    npz = bad / "tactile_right.npz"
    values = np.load(npz)["values"]
    with zipfile.ZipFile(npz, "w", zipfile.ZIP_DEFLATED) as z:
        buf = io.BytesIO()
        np.save(buf, values)
        z.writestr("values.npy", buf.getvalue())
        forged = npy_header((200_000_000,)) + np.arange(values.shape[0], dtype=np.int64).tobytes()
        z.writestr("timestamps_ns.npy", forged)
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "native", raw, out) == 1
    err = capsys.readouterr().err
    assert "tactile_right.npz [nat-rec_bad]" in err and "declares shape (200000000,)" in err
    assert [e["episode_id"] for e in load_episodes(out)] == ["nat-rec_good"]


def test_native_timestamps_declaring_far_more_rows_than_values_are_refused_unread(tmp_path, capsys):
    """Issue 26 item 6: a 0.84 MB deflated npz of 1e8 real timestamps beside a few hundred value rows reached
    862 MB before failing; now the header's row count is refused before a stamp is read (2e6 here: fast)."""
    import shutil

    raw = make_native(tmp_path / "raw")
    bad = raw / "rec_bad"
    shutil.copytree(raw / "rec_good", bad)
    npz = bad / "tactile_right.npz"
    values = np.load(npz)["values"]
    stamps = np.zeros(2_000_000, np.int64)
    stamps[:values.shape[0]] = np.load(npz)["timestamps_ns"]     # real stamps first: old code ingested it whole
    np.savez_compressed(npz, values=values, timestamps_ns=stamps)
    assert npz.stat().st_size < 100_000
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "native", raw, out) == 1
    err = capsys.readouterr().err
    assert f"timestamps_ns.npy declares 2000000 rows beside {values.shape[0]} value rows: refused" in err
    assert [e["episode_id"] for e in load_episodes(out)] == ["nat-rec_good"]


def test_standalone_npy_header_larger_than_file_is_refused(tmp_path):
    path = tmp_path / "video_timestamps.npy"
    path.write_bytes(npy_header((1_000_000_000,)) + np.arange(5, dtype=np.int64).tobytes())
    with pytest.raises(ValueError, match=r"declares shape \(1000000000,\).*holds 40 bytes"):
        check_npy_file(path)
    ok = tmp_path / "ok.npy"
    np.save(ok, np.arange(5, dtype=np.int64))
    assert check_npy_file(ok)[0] == (5,)


def test_hdf5_dataset_shape_beyond_its_storage_is_refused(tmp_path, capsys):
    raw = make_opentouch(tmp_path / "raw")
    with h5py.File(raw / "home_kitchen_p1.hdf5", "r+") as f:
        g = f["data/demo_02"]
        del g["timestamps"]
        ds = g.create_dataset("timestamps", shape=(7,), maxshape=(None,), chunks=(1024,), dtype="<i8")
        ds[:] = np.arange(7) * 33_333_333
        ds.resize((200_000_000,))   # declared 1.6 GB, stored one chunk
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", raw, out) == 1
    err = capsys.readouterr().err
    assert "home_kitchen_p1.hdf5 [ot-home_kitchen_p1-demo_02]" in err
    assert "declared shape (200000000,) int64 needs 1600000000 bytes" in err
    assert sorted(e["episode_id"] for e in load_episodes(out)) == ["ot-home_kitchen_p1-demo_003",
                                                                   "ot-home_kitchen_p1-demo_01"]


# --------------------------------------------------------------------------- bytes of other files (issue 26 item 5)

def _external_raw(g, outside: Path) -> None:
    rows = np.asarray(g["right_pressure"][()], np.float32)
    outside.write_bytes(rows.tobytes())
    del g["right_pressure"]
    g.create_dataset("right_pressure", shape=rows.shape, dtype=np.float32, external=[(str(outside), 0, rows.nbytes)])


def _external_link(g, outside: Path) -> None:
    with h5py.File(outside, "w") as o:
        o.create_dataset("p", data=np.asarray(g["right_pressure"][()], np.float32))
    del g["right_pressure"]
    g["right_pressure"] = h5py.ExternalLink(str(outside), "/p")


def _virtual(g, outside: Path) -> None:
    rows = np.asarray(g["right_pressure"][()], np.float32)
    with h5py.File(outside, "w") as o:
        o.create_dataset("p", data=rows)
    layout = h5py.VirtualLayout(shape=rows.shape, dtype=np.float32)
    layout[:] = h5py.VirtualSource(str(outside), "p", shape=rows.shape)
    del g["right_pressure"]
    g.create_virtual_dataset("right_pressure", layout)


@pytest.mark.parametrize("how,said", [(_external_raw, "stored in external raw file(s)"),
                                      (_external_link, "an HDF5 external link to"),
                                      (_virtual, "a virtual dataset mapping")])
def test_hdf5_reaching_another_file_is_refused(tmp_path, capsys, how, said):
    raw = make_opentouch(tmp_path / "raw")
    with h5py.File(raw / "home_kitchen_p1.hdf5", "r+") as f:
        how(f["data/demo_02"], tmp_path / "outside.bin")
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "opentouch", raw, out) == 1
    err = [line for line in capsys.readouterr().err.splitlines() if "demo_02" in line]
    assert len(err) == 1 and "/data/demo_02/right_pressure: " + said in err[0], err
    assert sorted(e["episode_id"] for e in load_episodes(out)) == ["ot-home_kitchen_p1-demo_003",
                                                                   "ot-home_kitchen_p1-demo_01"]


# --------------------------------------------------------------------------- non-regular files, symlinks

def test_fifo_named_chest_mp4_is_refused_not_hanging(tmp_path, capsys):
    raw = make_touchanything(tmp_path / "raw")
    video = raw / "Office" / "open_drawer" / "20260321_101010_001" / "chest.mp4"
    video.unlink()
    os.mkfifo(video)
    out = tmp_path / "ds"
    with deadline(60):
        assert ingest_cli("--pipeline", "touchanything", raw, out) == 1
    err = capsys.readouterr().err
    assert f"FAILED {video}" in err and "not a regular file (FIFO): refused" in err
    assert [e["episode_id"] for e in load_episodes(out)] == ["ta-Home-plug_usb-20260320_135743_682"]


def test_file_symlink_leaving_the_tree_is_refused_inside_is_followed(tmp_path):
    raw = make_touchanything(tmp_path / "raw")
    outside = make_touchanything(tmp_path / "elsewhere")
    folder = raw / "Office" / "open_drawer" / "20260321_101010_001"
    (folder / "pressure_grids.npz").unlink()
    (folder / "pressure_grids.npz").symlink_to(outside / "Home" / "plug_usb" / "20260320_135743_682" /
                                               "pressure_grids.npz")
    adapter = get_adapter("touchanything")
    refs, failures = adapter.discover_all(raw, {})
    assert [r.episode_id for r in refs] == ["ta-Home-plug_usb-20260320_135743_682"]
    (failure,) = failures
    assert failure.file == str(folder / "pressure_grids.npz") and "symlink leaves the source tree" in str(failure)
    # the same link pointing inside the tree is an ordinary file
    (folder / "pressure_grids.npz").unlink()
    (folder / "pressure_grids.npz").symlink_to(raw / "Home" / "plug_usb" / "20260320_135743_682" /
                                               "pressure_grids.npz")
    refs, failures = adapter.discover_all(raw, {})
    assert len(refs) == 2 and failures == []


def test_video_symlink_leaving_the_tree_is_refused(tmp_path):
    raw = make_touchanything(tmp_path / "raw")
    outside = tmp_path / "other.mp4"
    folder = raw / "Home" / "plug_usb" / "20260320_135743_682"
    (folder / "chest.mp4").rename(outside)
    (folder / "chest.mp4").symlink_to(outside)
    refs, failures = get_adapter("touchanything").discover_all(raw, {})
    assert len(refs) == 1 and len(failures) == 1
    assert failures[0].file == str(folder / "chest.mp4") and "leaves the source tree" in failures[0].message


def test_directory_symlinks_inside_found_once_at_real_path_outside_refused(tmp_path):
    raw = tmp_path / "raw"
    make_native(raw / "real")
    make_native(tmp_path / "elsewhere")
    (raw / "alias").symlink_to(raw / "real")                 # inside: the same recordings, found once
    (raw / "real" / "loop").symlink_to(raw)                  # a cycle: never walked twice
    (raw / "linked").mkdir()
    (raw / "linked" / "more").symlink_to(tmp_path / "elsewhere")   # outside: reported
    with deadline(30):
        refs, failures = get_adapter("native").discover_all(raw, {})
    assert [(r.episode_id, r.source_ref) for r in refs] == [("nat-rec_good", str(raw / "real" / "rec_good"))]
    (failure,) = failures
    assert failure.file == str(raw / "linked" / "more") and "directory symlink leaves the source tree" in str(failure)


# --------------------------------------------------------------------------- damaged H.264

def textured_frames(n: int) -> list[np.ndarray]:
    """Moving blurred noise: packets of several KB, like real footage (flat colours encode to ~100 bytes)."""
    rng = np.random.default_rng(3)
    base = cv2.GaussianBlur(rng.integers(0, 256, (480 + 40, 640 + 40, 3), dtype=np.uint8), (5, 5), 0)
    return [np.ascontiguousarray(base[i * 2:i * 2 + 480, i * 3:i * 3 + 640]) for i in range(n)]


def packets(path: Path) -> list[tuple[int, int]]:
    import av

    with av.open(str(path)) as c:
        return [(p.pos, p.size) for p in c.demux(c.streams.video[0]) if p.size]


def damaged_episode(root: Path, how: str) -> Path:
    lay = {h: load_layout(f"touchanything_{h}_21x21") for h in ("left", "right")}
    t = 8
    grids = {}
    for h in ("left", "right"):
        g = np.full((t, 21, 21), np.nan, np.float32)
        g[:, lay[h].live_mask] = 0.3
        grids[h] = g
    folder = root / "Home" / "pour" / "t1"
    write_touchanything_episode(folder, TouchAnythingEpisode(
        left_grid=grids["left"], right_grid=grids["right"], chest_frames=textured_frames(t),
        ts_epoch_s=1.7e9 + np.arange(t) / 30.0), wrist_videos=False)
    video = folder / "chest.mp4"
    data = bytearray(video.read_bytes())
    if how == "ff":           # 3000 x 0xFF in the middle of the largest packet (the key frame)
        pos, size = max(packets(video), key=lambda p: p[1])
        assert size > 6000
        start = pos + size // 2 - 1500
        data[start:start + 3000] = b"\xff" * 3000
    else:                     # random bytes over the second half of one inter-frame packet
        pos, size = max(packets(video)[1:], key=lambda p: p[1])
        rng = np.random.default_rng(7)
        data[pos + size // 2:pos + size] = rng.integers(0, 256, size - size // 2, dtype=np.uint8).tobytes()
    video.write_bytes(bytes(data))
    return video


@pytest.mark.parametrize("how", ["ff", "random"])
def test_damaged_h264_is_not_decoded_silently(tmp_path, how):
    video = damaged_episode(tmp_path / "raw", how)
    with pytest.raises(VideoError) as err:
        for _ in iter_video_rgb(video):
            pass
    assert err.value.frame is not None and f"frame {err.value.frame}" in str(err.value)
    if how == "random":   # concealed by the decoder (no error returned): caught by the corrupt-frame flag
        assert "concealed corrupt data" in str(err.value)


def test_damaged_h264_fails_its_episode_naming_file_and_frame(tmp_path, capsys):
    raw = make_touchanything(tmp_path / "raw")
    video = damaged_episode(raw, "random")
    with pytest.raises(VideoError) as damage:
        for _ in iter_video_rgb(video):
            pass
    n = damage.value.frame
    out = tmp_path / "ds"
    assert ingest_cli("--pipeline", "touchanything", raw, out) == 1
    err = capsys.readouterr().err
    assert f"FAILED {video} [ta-Home-pour-t1] frame {n}: video frame {n} is damaged" in err
    assert len(load_episodes(out)) == 2
    (failure,) = report_of(out)["failures"]
    assert failure["file"] == str(video) and failure["frame"] == n


def test_clean_textured_h264_decodes_every_frame(tmp_path):
    from htdata.synthetic.formats.media import write_h264

    path = tmp_path / "clean.mp4"
    write_h264(path, textured_frames(8))
    assert sum(1 for _ in iter_video_rgb(path)) == 8


def test_0xff_run_in_key_frame_concealed_by_decoder_is_caught(tmp_path):
    # FFmpeg returns no error for this damage (it conceals it and outputs a smeared picture):
    # only the frame's corrupt flag tells, and it must fail the read naming the frame.
    from htdata.synthetic.formats.media import write_h264

    path = tmp_path / "ego.mp4"
    write_h264(path, textured_frames(8))
    data = bytearray(path.read_bytes())
    pos, size = max(packets(path), key=lambda p: p[1])
    start = pos + size // 3
    data[start:start + 3000] = b"\xff" * 3000
    path.write_bytes(bytes(data))
    with pytest.raises(VideoError, match="video frame 0 is damaged: the decoder concealed corrupt data"):
        for _ in iter_video_rgb(path):
            pass


def _gzip_zeros(nbytes: int) -> bytes:
    """gzip (zlib stream, as HDF5's deflate filter stores it) of `nbytes` zero bytes, made block by block."""
    import zlib

    z, block, out = zlib.compressobj(1), bytes(16 << 20), []
    for _ in range(nbytes // len(block)):
        out.append(z.compress(block))
    out.append(z.flush())
    return b"".join(out)


def test_an_hdf5_gzip_bomb_chunk_is_refused_before_it_is_inflated(tmp_path):
    """One 1 GiB gzip chunk (about 1 MB on disk) as a clip's pressure: the old size check passed it (the declared
    shape fits the file's 1100:1 ratio) and reading one row inflated the whole chunk (~1.1 GB peak)."""
    from tests.factories.hostile import peak_rss_mb

    raw = make_opentouch(tmp_path / "raw")
    rows = (1 << 30) // (16 * 16 * 4)                      # 1 GiB of float32 16x16 rows in one chunk
    with h5py.File(raw / "home_kitchen_p1.hdf5", "r+") as f:
        g = f["data/demo_02"]
        n = int(g["timestamps"].shape[0])
        del g["right_pressure"]
        ds = g.create_dataset("right_pressure", shape=(n, 16, 16), maxshape=(None, 16, 16), chunks=(rows, 16, 16),
                              dtype="<f4", compression="gzip")
        ds.id.write_direct_chunk((0, 0, 0), _gzip_zeros(rows * 16 * 16 * 4))
    out = tmp_path / "ds"
    text, peak = peak_rss_mb(f"""
import sys
sys.stderr = sys.stdout                                  # the one-line error, read back below
from htdata.cli import main
rc = main(["ingest", "--workers", "0", "--quiet", "--pipeline", "opentouch", {str(raw)!r}, {str(out)!r}])
print("RC", rc)
""")
    assert "RC 1" in text and peak < 500, (f"peak {peak:.0f} MB", text)
    assert "home_kitchen_p1.hdf5 [ot-home_kitchen_p1-demo_02]" in text and f"chunk shape ({rows}, 16, 16)" in text, text
    episodes = sorted(e["episode_id"] for e in load_episodes(out))
    assert "ot-home_kitchen_p1-demo_02" not in episodes and episodes, episodes


@pytest.mark.parametrize("offset", ["1e308", "9223372036800000000"])   # the second + 0.3 s wraps int64
def test_a_clock_offset_beyond_int64_names_the_field(tmp_path, capsys, offset):
    """Issue 44 weak edge: clock_offset_ns 1e308 was a bare OverflowError (and a large int64 one a silent wrap)."""
    raw = make_native(tmp_path / "raw")
    rec = raw / "rec_good" / "recording.json"
    doc = json.loads(rec.read_text())
    text = json.dumps(doc).replace('"clock_offset_ns": 0', f'"clock_offset_ns": {offset}')
    assert text != json.dumps(doc)
    rec.write_text(text)
    assert ingest_cli("--pipeline", "native", raw, tmp_path / "ds") in (1, 2)
    err = capsys.readouterr().err
    assert "Traceback" not in err and "OverflowError" not in err, err
    assert "rec_good" in err and "clock_offset_ns" in err, err


def _h264_segment(path: Path, width: int, height: int, frames: int) -> bytes:
    import av

    with av.open(str(path), "w", format="h264") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = width, height, "yuv420p"
        for i in range(frames):
            frame = av.VideoFrame.from_ndarray(np.full((height, width, 3), 40 * i, np.uint8), format="rgb24")
            for p in s.encode(frame):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path.read_bytes()


def test_a_video_that_grows_past_the_frame_limit_mid_stream_fails_at_that_frame(tmp_path):
    """Issue 44 item 1: the size check read the container's first declaration only; a stream whose SPS
    switches to a larger picture after its first frames decoded it (12000x12000: ~850 MB, rc 0)."""
    small = _h264_segment(tmp_path / "a.h264", 320, 240, 4)
    big = _h264_segment(tmp_path / "b.h264", 4200, 4200, 1)        # 17.6 Mpx: over the 16.8 Mpx limit
    video = tmp_path / "grows.h264"
    video.write_bytes(small + big)
    got = []
    with pytest.raises(VideoError) as info:
        for rgb in iter_video_rgb(video):
            got.append(rgb.shape)
    # the decoder holds a few frames back: some of the small ones come out before the refusal, never a big one
    assert got and set(got) == {(240, 320, 3)} and "16.8 Mpx" in str(info.value), (got, str(info.value))


def _mp4(path: Path, width: int = 320, height: int = 240, frames: int = 6) -> Path:
    import av

    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = width, height, "yuv420p"
        for i in range(frames):
            for p in s.encode(av.VideoFrame.from_ndarray(np.full((height, width, 3), 30 * i, np.uint8), format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


def test_the_mp4_header_is_read_before_ffmpeg_opens_the_file(tmp_path):
    from htdata.source.adapters.mp4header import Mp4HeaderError, check_mp4_header

    video = _mp4(tmp_path / "ok.mp4")
    check_mp4_header(video, 320 * 240)                     # the SPS found and read: 320x240 exactly
    with pytest.raises(Mp4HeaderError, match="320x240"):
        check_mp4_header(video, 320 * 240 - 1)
    assert len(list(iter_video_rgb(video))) == 6


def test_an_mp4_declaring_3e7_samples_is_refused_before_ffmpeg_indexes_them(tmp_path):
    """Issue 44 item 2: av.open built an index of every declared sample before any check (the audit: ~1.16 GB;
    this file, 30 MB declaring 3e7 one-byte samples: av.open alone peaked at ~400 MB here)."""
    import struct

    from tests.factories.hostile import peak_rss_mb

    video = _mp4(tmp_path / "many.mp4")
    data = bytearray(video.read_bytes())
    at = data.find(b"stsz") + 4 + 4                        # type, version/flags: then sample_size, count
    data[at:at + 8] = struct.pack(">II", 1, 30_000_000)    # every sample one byte: 3e7 of them fit in 30 MB
    data += struct.pack(">I4s", 30_000_008, b"free") + bytes(30_000_000)
    video.write_bytes(bytes(data))
    text, peak = peak_rss_mb(f"""
from htdata.source.adapters.video import VideoError, iter_video_rgb
try:
    list(iter_video_rgb({str(video)!r}))
    print("DECODED")
except VideoError as exc:
    print("REFUSED", exc)
""")
    assert "REFUSED" in text and "30000000 samples" in text and peak < 150, (text, peak)   # the interpreter, av


def test_an_sps_declaring_16000x16000_is_read_as_such():
    """The avcC path of the header check, on an SPS written bit by bit (baseline profile, 1000x1000 macroblocks)."""
    from htdata.source.adapters.mp4header import Mp4HeaderError, _check_avcc, sps_picture_size

    bits = "".join(f"{v:08b}" for v in (66, 0, 40))          # profile_idc, constraints, level_idc

    def ue(v: int) -> str:
        code = bin(v + 1)[2:]
        return "0" * (len(code) - 1) + code
    bits += ue(0) + ue(0) + ue(0) + ue(0) + ue(1) + "0" + ue(999) + ue(999) + "1" + "1"
    bits += "0" * (-len(bits) % 8)
    nal = bytes([0x67]) + int(bits, 2).to_bytes(len(bits) // 8, "big")
    assert sps_picture_size(nal) == (16000, 16000)
    avcc = bytes([1, 66, 0, 40, 0xFF, 0xE1]) + len(nal).to_bytes(2, "big") + nal
    with pytest.raises(Mp4HeaderError, match="16000x16000"):
        _check_avcc(avcc, 1 << 24)
