"""RGB trade-offs: JPEG quality vs bytes vs PSNR, resize method vs time vs error.

Frames come from the synthetic world at camera resolution, so the numbers
describe the kind of frames `htdata ingest` sees in the demo.
"""

from __future__ import annotations

import cv2
import numpy as np

from htdata.benchmarks.timing import best_ms


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
