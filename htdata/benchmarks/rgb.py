"""RGB trade-offs: JPEG quality vs bytes vs PSNR, resize method vs time vs error.

Frames are decoded source frames of the sample corpus at camera resolution
(bench.py reads them through the adapters), i.e. what `htdata ingest` sees.

Imports inside functions: the JPEG header reader and the sample H.264 writer, only when the rows that
decode JPEG at reduced scale or resize in the video decoder are measured.
"""

from __future__ import annotations

import cv2
import numpy as np

from htdata.benchmarks.timing import best_ms
from htdata.source.rgb import resize_cubic2x_area
from htdata.source.rgbsettings import RgbConfig

# The criteria the section's defaults are computed by (stated in REPORT.md next to the tables).
PSNR_TARGET_DB = 40.0
QUALITY_CRITERION = f"the smallest JPEG quality whose mean PSNR is at least {PSNR_TARGET_DB:g} dB"
RESIZE_CRITERION = "the lowest mean error against the reference among the pipeline's [rgb] interpolation options"
# [rgb] interpolation -> the method row measuring it (htdata.source.rgb resizes with cv2)
PIPELINE_RESIZE = {"area": "cv2_area", "linear": "cv2_linear", "cubic": "cv2_cubic", "nearest": "cv2_nearest",
                   "cubic2x_area": "cv2_cubic2x_area"}


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0**2 / mse)


def jpeg_quality_rows(frames224: list[np.ndarray], qualities=(75, 85, 90, 95, 98)) -> list[dict]:
    rows = []
    for q in qualities:
        params = [cv2.IMWRITE_JPEG_QUALITY, int(q)]
        sizes, scores = [], []
        for f in frames224:
            ok, buf = cv2.imencode(".jpg", f, params)
            assert ok
            sizes.append(buf.nbytes)
            scores.append(psnr(f, cv2.imdecode(buf, cv2.IMREAD_COLOR)))
        f0 = frames224[0]
        enc = best_ms(lambda: cv2.imencode(".jpg", f0, params), number=20)
        buf0 = cv2.imencode(".jpg", f0, params)[1]
        dec = best_ms(lambda: cv2.imdecode(buf0, cv2.IMREAD_COLOR), number=20)
        rows.append({"quality": q, "bytes_per_frame": float(np.mean(sizes)),
                     "psnr_db": float(np.mean(scores)), "encode_ms": enc, "decode_ms": dec})
    return rows


def _square(frame: np.ndarray) -> np.ndarray:
    h, w = frame.shape[:2]
    s = min(h, w)
    y, x = (h - s) // 2, (w - s) // 2
    return frame[y:y + s, x:x + s]


def area_after_box_prestep(sq: np.ndarray, size: int = 224, keep: int = 2) -> np.ndarray:
    """Candidate faster resize (issue #47): an integer-factor INTER_AREA box step (cv2's fast path) down to at
    least `keep` x the target, then INTER_AREA to `size`. The square is first trimmed symmetrically to a
    multiple of the factor, so the content stays centred. keep=1 is the cheapest, keep=2 keeps more detail."""
    k = sq.shape[0] // (size * keep)
    if k < 2:
        return cv2.resize(sq, (size, size), interpolation=cv2.INTER_AREA)
    side = sq.shape[0] // k * k
    t = (sq.shape[0] - side) // 2
    small = cv2.resize(np.ascontiguousarray(sq[t:t + side, t:t + side]), (side // k, side // k),
                       interpolation=cv2.INTER_AREA)
    return cv2.resize(small, (size, size), interpolation=cv2.INTER_AREA)


def interp_then_box(sq: np.ndarray, size: int = 224, first: int = cv2.INTER_CUBIC, k: int = 2) -> np.ndarray:
    """Candidate faster resize (issue #47): interpolate (no anti-aliasing) to exactly k x the target, then an
    integer k x k INTER_AREA box (cv2's fast path) to `size`. The box does the anti-aliasing; the first step
    only has to resample, at a ratio near 1."""
    big = cv2.resize(sq, (size * k, size * k), interpolation=first)
    return cv2.resize(big, (size, size), interpolation=cv2.INTER_AREA)


def cubic2x_area_16s(sq: np.ndarray, size: int = 224) -> np.ndarray:
    """Candidate (issue #47): cubic2x_area with the 448 intermediate kept in 16-bit fixed point (x64, int16:
    cubic overshoot stays signed), so the box averages unrounded values; one rounding at the end."""
    x = sq.astype(np.int16) * np.int16(64)     # (cv2.multiply to CV_16S is ~5x slower here)
    big = cv2.resize(x, (size * 2, size * 2), interpolation=cv2.INTER_CUBIC)
    small = cv2.resize(big, (size, size), interpolation=cv2.INTER_AREA)
    return cv2.convertScaleAbs(np.maximum(small, 0), alpha=1 / 64)   # clip the undershoot, round, saturate


def halve_then(sq: np.ndarray, size: int = 224, second: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Candidate (issue #47): a 2x2 box to half the side (what a JPEG decoded at 1/2 scale in the DCT gives,
    near enough), then `second` to `size`. An odd side drops its last row/column."""
    n = sq.shape[0] // 2 * 2
    half = cv2.resize(np.ascontiguousarray(sq[:n, :n]), (n // 2, n // 2), interpolation=cv2.INTER_AREA)
    return cv2.resize(half, (size, size), interpolation=second)


def prefilter_then_cubic(sq: np.ndarray, size: int = 224, a: float = 0.22) -> np.ndarray:
    """Candidate (issue #47): a separable 3-tap blur [a, 1-2a, a] at source resolution (float32, so nothing is
    rounded twice), then INTER_CUBIC (no anti-aliasing) to `size`. a = 0.22 measured best at 480-512 px
    sources (0.20-0.26 tried); the right blur depends on the ratio."""
    k = np.array([a, 1 - 2 * a, a], np.float32)
    blurred = cv2.sepFilter2D(sq, cv2.CV_32F, k, k, borderType=cv2.BORDER_REFLECT)
    out = cv2.resize(blurred, (size, size), interpolation=cv2.INTER_CUBIC)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


# The target for a cheaper resize: at most this share of cv2_area's time, no more mean error.
CANDIDATE_TIME_SHARE = 0.25
CANDIDATE_RULE = (f"at most {CANDIDATE_TIME_SHARE:g}x today's path's ms/frame and a mean error no larger than "
                  "its, both measured in this run")


def candidate_verdicts(rows: list[dict], base: str = "cv2_area", time_key: str = "ms_per_frame") -> list[dict]:
    """Each row's time and mean error as ratios of `base`'s, and whether it meets CANDIDATE_RULE."""
    ref = next(r for r in rows if r["method"] == base)
    out = []
    for r in rows:
        t = r[time_key] / ref[time_key] if ref[time_key] else float("inf")
        e = r["mean_abs_error"] / ref["mean_abs_error"] if ref["mean_abs_error"] else float("inf")
        out.append({"method": r["method"], "time_ratio": t, "error_ratio": e,
                    "meets": r["method"] != base and t <= CANDIDATE_TIME_SHARE and e <= 1.0})
    return out


def reduced_decode_square(buf: np.ndarray, size: int = 224, interpolation: int = cv2.INTER_AREA) -> np.ndarray | None:
    """Candidate (issue #47): a JPEG decoded at 1/2 scale (libjpeg's scaled IDCT, cv2.IMREAD_REDUCED_COLOR_2),
    centre square, resized to `size`. None where that cannot stand for the full-size path: the reduced
    square would be smaller than the target, or the crop offset is odd (a half-pixel shift at 1/2 scale)."""
    from htdata.format.imageheader import jpeg_size

    hw = jpeg_size(memoryview(np.ascontiguousarray(buf)))
    if hw is None:
        return None
    h, w = hw
    side = min(h, w)
    if side // 2 < size or (h - side) % 4 or (w - side) % 4 or h % 2 or w % 2:
        return None
    img = cv2.imdecode(buf, cv2.IMREAD_REDUCED_COLOR_2)
    return cv2.resize(np.ascontiguousarray(_square(img)), (size, size), interpolation=interpolation)


def jpeg_reduced_rows(frames: list[np.ndarray], size: int = 224, quality: int = 95) -> list[dict]:
    """Decode + resize per frame of the source frames as JPEG sources (re-encoded at `quality`): full decode
    + cv2_area against a 1/2-scale DCT decode + area / linear, errors against the full decode's reference."""
    bufs = [cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, quality])[1] for f in frames]
    full = [np.ascontiguousarray(_square(cv2.imdecode(b, cv2.IMREAD_COLOR))) for b in bufs]
    refs = [_reference(sq, size) for sq in full]
    methods = {
        "jpeg_full_decode+cv2_area": lambda b: cv2.resize(np.ascontiguousarray(_square(cv2.imdecode(b, cv2.IMREAD_COLOR))),
                                                          (size, size), interpolation=cv2.INTER_AREA),
        "jpeg_full_decode+cubic2x_area": lambda b: interp_then_box(
            np.ascontiguousarray(_square(cv2.imdecode(b, cv2.IMREAD_COLOR))), size),
        "jpeg_reduced2_decode+area": lambda b: reduced_decode_square(b, size, cv2.INTER_AREA),
        "jpeg_reduced2_decode+linear": lambda b: reduced_decode_square(b, size, cv2.INTER_LINEAR),
    }
    rows = []
    for name, fn in methods.items():
        outs = [fn(b) for b in bufs]
        if any(o is None for o in outs):
            continue   # the reduced decode does not apply at this source size
        errs = [np.abs(o.astype(np.float32) - r) for o, r in zip(outs, refs)]
        rows.append({"method": name, "ms_per_frame": best_ms(lambda: fn(bufs[0]), number=5),
                     "mean_abs_error": float(np.mean([e.mean() for e in errs])) / 255.0,
                     "max_abs_error": float(max(e.max() for e in errs)) / 255.0,
                     "source_size": f"{frames[0].shape[1]}x{frames[0].shape[0]}"})
    return rows


def video_scale_rows(frames: list[np.ndarray], size: int = 224) -> list[dict]:
    """Resize in the video decoder (issue #47): the centre squares of the source frames encoded as H.264
    (yuv420p, as the sample corpus and most cameras), decoded with PyAV, then either converted to RGB at full
    size + cv2_area (what the ingest does) or scaled by FFmpeg's swscale during the YUV -> RGB conversion
    (`VideoFrame.reformat(size, size, interpolation=...)`), or swscale to 2x the target + an integer box.
    Per frame: the conversion and resize after the decode (the decode is the same for all). Errors against
    the reference of the full-size RGB conversion. Square sources only: reformat cannot crop."""
    import tempfile
    from pathlib import Path

    import av

    from htdata.synthetic.formats.media import write_h264

    squares = [np.ascontiguousarray(_square(f)) for f in frames]
    side = squares[0].shape[0] // 2 * 2
    squares = [np.ascontiguousarray(sq[:side, :side]) for sq in squares]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "squares.mp4"
        write_h264(path, squares)
        with av.open(str(path)) as container:
            decoded = list(container.decode(video=0))
    refs = [_reference(vf.to_ndarray(format="rgb24"), size) for vf in decoded]

    def swscale(interp, k=1):
        def fn(vf):
            out = vf.reformat(width=size * k, height=size * k, format="rgb24", interpolation=interp).to_ndarray()
            return out if k == 1 else cv2.resize(out, (size, size), interpolation=cv2.INTER_AREA)
        return fn

    methods = {
        "video_rgb24+cv2_area": lambda vf: cv2.resize(vf.to_ndarray(format="rgb24"), (size, size),
                                                      interpolation=cv2.INTER_AREA),
        "video_rgb24+cubic2x_area": lambda vf: interp_then_box(vf.to_ndarray(format="rgb24"), size),
        "swscale_area": swscale("AREA"),
        "swscale_bicubic": swscale("BICUBIC"),
        "swscale_lanczos": swscale("LANCZOS"),
        "swscale_bicubic2x_area": swscale("BICUBIC", 2),
    }
    rows = []
    for name, fn in methods.items():
        errs = [np.abs(fn(vf).astype(np.float32) - r) for vf, r in zip(decoded, refs)]
        rows.append({"method": name, "ms_per_frame": best_ms(lambda: fn(decoded[0]), number=5),
                     "mean_abs_error": float(np.mean([e.mean() for e in errs])) / 255.0,
                     "max_abs_error": float(max(e.max() for e in errs)) / 255.0,
                     "source_size": f"{side}x{side}"})
    return rows


def _reference(sq: np.ndarray, size: int) -> np.ndarray:
    """Supersampled reference: Lanczos to 4x the target, then exact 4x4 box average (float)."""
    big = cv2.resize(sq.astype(np.float32), (size * 4, size * 4), interpolation=cv2.INTER_LANCZOS4)
    return big.reshape(size, 4, size, 4, 3).mean(axis=(1, 3))


def resize_rows(frames: list[np.ndarray], size: int = 224) -> list[dict]:
    """Resize methods against a high-quality reference (Lanczos on float, then area)."""
    import torch
    import torch.nn.functional as F

    squares = [np.ascontiguousarray(_square(f)) for f in frames]

    def reference(sq):
        return _reference(sq, size)

    def torch_bilinear_aa(sq):
        t = torch.from_numpy(sq).permute(2, 0, 1)[None]
        out = F.interpolate(t.float(), size=(size, size), mode="bilinear", antialias=True, align_corners=False)
        return out[0].permute(1, 2, 0).clamp(0, 255).round().to(torch.uint8).numpy()

    methods = {
        "cv2_area": lambda sq: cv2.resize(sq, (size, size), interpolation=cv2.INTER_AREA),
        "cv2_linear": lambda sq: cv2.resize(sq, (size, size), interpolation=cv2.INTER_LINEAR),
        "cv2_nearest": lambda sq: cv2.resize(sq, (size, size), interpolation=cv2.INTER_NEAREST),
        "cv2_cubic": lambda sq: cv2.resize(sq, (size, size), interpolation=cv2.INTER_CUBIC),
        "torch_bilinear_antialias": torch_bilinear_aa,
        # Not pipeline options: candidates for a cheaper resize, measured by the same reference.
        "cv2_area_box_prestep_1x": lambda sq: area_after_box_prestep(sq, size, keep=1),
        "cv2_area_box_prestep_2x": lambda sq: area_after_box_prestep(sq, size, keep=2),
        "cv2_cubic2x_area": lambda sq: resize_cubic2x_area(sq, size),   # the pipeline's option, = interp_then_box
        "cv2_cubic2x_area_16s": lambda sq: cubic2x_area_16s(sq, size),
        "cv2_linear2x_area": lambda sq: interp_then_box(sq, size, cv2.INTER_LINEAR, 2),
        "cv2_cubic3x_area": lambda sq: interp_then_box(sq, size, cv2.INTER_CUBIC, 3),
        "cv2_lanczos2x_area": lambda sq: interp_then_box(sq, size, cv2.INTER_LANCZOS4, 2),
        "prefilter_cubic": lambda sq: prefilter_then_cubic(sq, size),
        "box_half_linear": lambda sq: halve_then(sq, size, cv2.INTER_LINEAR),
        "box_half_cubic": lambda sq: halve_then(sq, size, cv2.INTER_CUBIC),
    }
    refs = [reference(sq) for sq in squares]
    rows = []
    for name, fn in methods.items():
        errs = [np.abs(fn(sq).astype(np.float32) - ref) for sq, ref in zip(squares, refs)]
        ms = best_ms(lambda: fn(squares[0]), number=5)
        rows.append({"method": name, "ms_per_frame": ms,
                     "mean_abs_error": float(np.mean([e.mean() for e in errs])) / 255.0,
                     "max_abs_error": float(max(e.max() for e in errs)) / 255.0,
                     "source_size": f"{frames[0].shape[1]}x{frames[0].shape[0]}"})
    return rows


def rgb_defaults(quality: list[dict], resize: list[dict]) -> dict:
    """The JPEG quality and resize method the criteria pick from the measured rows, and why."""
    good = sorted((r for r in quality if r["psnr_db"] >= PSNR_TARGET_DB), key=lambda r: r["quality"])
    q = good[0] if good else max(quality, key=lambda r: r["psnr_db"])
    q_why = (f"q{q['quality']}: {q['psnr_db']:.1f} dB at {q['bytes_per_frame'] / 1024:.1f} KiB"
             + ("" if good else f" (no quality reaches {PSNR_TARGET_DB:g} dB: the best one)"))
    below = [r for r in quality if r["quality"] < q["quality"]]
    if below:
        b = max(below, key=lambda r: r["quality"])
        q_why += f"; q{b['quality']}: {b['psnr_db']:.1f} dB at {b['bytes_per_frame'] / 1024:.1f} KiB"
    usable = [r for r in resize if r["method"] in PIPELINE_RESIZE.values()]
    m = min(usable, key=lambda r: r["mean_abs_error"])
    best = min(resize, key=lambda r: r["mean_abs_error"])
    m_why = (f"{m['method']}: mean error {m['mean_abs_error']:.4f} in {m['ms_per_frame']:.2f} ms"
             + ("" if best is m else f" (lowest of all methods: {best['method']} {best['mean_abs_error']:.4f}, "
                                     "not a pipeline option)"))
    return {"quality": q["quality"], "resize": m["method"], "quality_reason": q_why, "resize_reason": m_why}


def rgb_section(frames: list[np.ndarray], size: int = 224) -> dict:
    """Both RGB tables plus the defaults the criteria compute from them, beside the pipeline's defaults."""

    if not frames:
        raise ValueError("rgb benchmark needs at least one source frame")
    squares224 = [cv2.resize(np.ascontiguousarray(_square(f)), (size, size), interpolation=cv2.INTER_AREA)
                  for f in frames]
    quality = jpeg_quality_rows(squares224)
    resize = resize_rows(frames, size)
    reduced = jpeg_reduced_rows(frames, size)
    video = video_scale_rows(frames, size)
    chosen = rgb_defaults(quality, resize)
    code = RgbConfig()
    code_resize = PIPELINE_RESIZE[code.interpolation]
    same = chosen["quality"] == code.quality and chosen["resize"] == code_resize
    reason = (f"JPEG by {QUALITY_CRITERION}: {chosen['quality_reason']}; resize by {RESIZE_CRITERION}: "
              f"{chosen['resize_reason']}; the pipeline defaults ([rgb] quality {code.quality}, interpolation "
              f"{code.interpolation!r} = {code_resize}) are " + ("the same" if same else "DIFFERENT"))
    return {"frames": len(frames), "source_size": resize[0]["source_size"], "jpeg": quality, "resize": resize,
            "default_quality": chosen["quality"], "default_resize": chosen["resize"],
            "code_default_quality": code.quality, "code_default_resize": code_resize, "reason": reason,
            "candidate_rule": CANDIDATE_RULE, "resize_verdicts": candidate_verdicts(resize),
            "jpeg_reduced": reduced,
            "jpeg_reduced_verdicts": candidate_verdicts(reduced, "jpeg_full_decode+cv2_area") if reduced else [],
            "video_scale": video, "video_scale_verdicts": candidate_verdicts(video, "video_rgb24+cv2_area")}
