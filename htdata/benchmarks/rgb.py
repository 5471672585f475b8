"""RGB trade-offs: JPEG quality vs bytes vs PSNR, resize method vs time vs error.

Frames are decoded source frames of the sample corpus at camera resolution
(bench.py reads them through the adapters), i.e. what `htdata ingest` sees.
"""

from __future__ import annotations

import cv2
import numpy as np

from htdata.benchmarks.timing import best_ms
from htdata.codec import DEFAULT_CODEC_INFO

DEFAULT_QUALITY = int(DEFAULT_CODEC_INFO["rgb"]["quality"])
DEFAULT_RESIZE = "cv2_area"   # what htdata.rgb.to_square_224 does with interpolation="area"


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
        "torch_bilinear_antialias": torch_bilinear_aa,
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


def rgb_section(frames: list[np.ndarray], size: int = 224) -> dict:
    """Both RGB tables plus the defaults and the numbers behind them."""
    if not frames:
        raise ValueError("rgb benchmark needs at least one source frame")
    squares224 = [cv2.resize(np.ascontiguousarray(_square(f)), (size, size), interpolation=cv2.INTER_AREA)
                  for f in frames]
    quality = jpeg_quality_rows(squares224)
    resize = resize_rows(frames, size)
    q = {r["quality"]: r for r in quality}
    r = {row["method"]: row for row in resize}
    reason = []
    if DEFAULT_QUALITY in q and 90 in q and DEFAULT_QUALITY != 90:
        reason.append(f"JPEG q{DEFAULT_QUALITY}: {q[DEFAULT_QUALITY]['psnr_db']:.1f} dB at "
                      f"{q[DEFAULT_QUALITY]['bytes_per_frame'] / 1024:.1f} KiB vs q90 {q[90]['psnr_db']:.1f} dB at "
                      f"{q[90]['bytes_per_frame'] / 1024:.1f} KiB")
    area, best = r[DEFAULT_RESIZE], min(resize, key=lambda row: row["mean_abs_error"])
    reason.append(f"resize {DEFAULT_RESIZE}: mean error {area['mean_abs_error']:.4f} in {area['ms_per_frame']:.2f} ms "
                  f"(lowest error: {best['method']} {best['mean_abs_error']:.4f} in {best['ms_per_frame']:.2f} ms)")
    return {"frames": len(frames), "source_size": resize[0]["source_size"], "jpeg": quality, "resize": resize,
            "default_quality": DEFAULT_QUALITY, "default_resize": DEFAULT_RESIZE, "reason": "; ".join(reason)}
