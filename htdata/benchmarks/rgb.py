"""RGB trade-offs: JPEG quality vs bytes vs PSNR, resize method vs time vs error.

Frames are decoded source frames of the sample corpus at camera resolution
(bench.py reads them through the adapters), i.e. what `htdata ingest` sees.
"""

from __future__ import annotations

import cv2
import numpy as np

from htdata.benchmarks.timing import best_ms
from htdata.source.rgbsettings import RgbConfig

# The criteria the section's defaults are computed by (stated in REPORT.md next to the tables).
PSNR_TARGET_DB = 40.0
QUALITY_CRITERION = f"the smallest JPEG quality whose mean PSNR is at least {PSNR_TARGET_DB:g} dB"
RESIZE_CRITERION = "the lowest mean error against the reference among the pipeline's [rgb] interpolation options"
# [rgb] interpolation -> the method row measuring it (htdata.source.rgb resizes with cv2)
PIPELINE_RESIZE = {"area": "cv2_area", "linear": "cv2_linear", "cubic": "cv2_cubic", "nearest": "cv2_nearest"}


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


def resize_rows(frames: list[np.ndarray], size: int = 224) -> list[dict]:
    """Resize methods against a high-quality reference (Lanczos on float, then area)."""
    import torch
    import torch.nn.functional as F

    squares = [np.ascontiguousarray(_square(f)) for f in frames]

    def reference(sq):
        # Supersampled reference: Lanczos to 4x the target, then exact 4x4 box average.
        big = cv2.resize(sq.astype(np.float32), (size * 4, size * 4), interpolation=cv2.INTER_LANCZOS4)
        return big.reshape(size, 4, size, 4, 3).mean(axis=(1, 3))

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
    chosen = rgb_defaults(quality, resize)
    code = RgbConfig()
    code_resize = PIPELINE_RESIZE[code.interpolation]
    same = chosen["quality"] == code.quality and chosen["resize"] == code_resize
    reason = (f"JPEG by {QUALITY_CRITERION}: {chosen['quality_reason']}; resize by {RESIZE_CRITERION}: "
              f"{chosen['resize_reason']}; the pipeline defaults ([rgb] quality {code.quality}, interpolation "
              f"{code.interpolation!r} = {code_resize}) are " + ("the same" if same else "DIFFERENT"))
    return {"frames": len(frames), "source_size": resize[0]["source_size"], "jpeg": quality, "resize": resize,
            "default_quality": chosen["quality"], "default_resize": chosen["resize"],
            "code_default_quality": code.quality, "code_default_resize": code_resize, "reason": reason}
