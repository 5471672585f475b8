"""Tactile-video lag from the content of an episode (`[sync] lag = "estimate"`).

Clocks of real rigs disagree: a glove stamped by its own clock can run tens
or hundreds of ms off the camera's. The lag is estimated per episode from
what the two streams show, then (when the pipeline asks and the estimate is
confident) subtracted from the tactile timestamps before `sync.pair`.

Sign: `lag_ns` = tactile timestamp - RGB timestamp of the same event. A glove
that stamps every row 100 ms late has lag +100 ms; applying it shifts every
tactile timestamp by -100 ms onto the RGB clock (what the samples then store
as t_tactile_ns; the sync report keeps the lag, so the recorded stamps are
t_tactile_ns + lag_ns).

Estimator (`estimate_lag`): the camera sees the hand, the glove feels what
the hand touches, so at the right lag the contact is a function of the
picture: two frames that look alike carry the same total contact, on the way
in (contact onset) and on the way out (release) alike. At a wrong lag the
onset and the release disagree in opposite directions (hysteresis). So:
- picture: each RGB frame as a grey 32x32 thumbnail, projected on its first
  principal components; for every frame, its NEIGHBOURS nearest look-alike
  frames at least max(max_lag, MIN_EXCLUDE_S) away in time (temporal
  neighbours agree whatever the lag, so they say nothing about it) and at
  most SEARCH_S away (cost linear in episode length);
- contact: the normalised live taxels' mean per tactile row (hands summed),
  read at t_rgb + lag by linear interpolation;
- residual(lag) = mean (contact_i - mean of its look-alikes' contact)^2 /
  variance of the contact, on a lag grid over [-max_lag, max_lag], minimum
  refined by a parabola through its neighbours (sub-frame);
- confidence = 1 - residual(best) / median residual over the searched range
  (0: the picture does not predict the contact better at one lag than at any
  other; 1: perfectly at one lag only).
Cross-correlating contact with RGB motion energy was tried first: it is
biased whenever reaching in and reaching out differ in speed (motion stops
at contact, but not symmetrically), which the sample world's episodes do.

It declines (confidence 0, nothing applied, `why` says which) on episodes
too short to compare, on flat video, on contact that never changes, and
when the best lag sits on the edge of the searched range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from htdata._moved import moved_name
from htdata.glove.layouts import load_layout
from htdata.glove.normalise import Normaliser
from htdata.glove.normalisesettings import NormaliseSettings
from htdata.source.syncsettings import SyncConfig

THUMB = 32                  # grey thumbnails THUMB x THUMB
COMPONENTS = 16             # principal components of the thumbnails used to find look-alikes
PCA_FRAMES = 256            # frames the principal components are computed from
NEIGHBOURS = 3              # look-alike frames per frame
MIN_FRAMES = 24             # frames with look-alikes needed (below: "too short")
MIN_EXCLUDE_S = 0.3         # look-alikes lie at least max(max_lag, this) apart in time
CONTACT_STD_MIN = 1e-3      # std of the mean contact (unit values) below which contact "never changes"
FLAT_VIDEO_MAX = 0.5        # grey levels: largest per-pixel std over time below this = flat video
LAG_STEP_S = 0.005          # lag grid before the parabolic refinement
QUERY_BLOCK = 512           # frames per block of the look-alike search (memory bound)
SEARCH_S = 60.0             # look-alikes are searched within this many seconds of a frame (linear cost)


@dataclass
class LagEstimate:
    """What the content says about one episode's lag."""

    lag_ns: int | None        # tactile - RGB clock; None when it could not be measured
    confidence: float         # in [0, 1] (see the module docstring); 0 when declined
    why: str = ""             # why the estimate should not be trusted ("" when it can)
    frames: int = 0           # RGB frames compared
    residual: float | None = None   # residual at the best lag (0 = contact fully predicted)

    def to_dict(self) -> dict:
        return {"lag_ms": None if self.lag_ns is None else self.lag_ns / 1e6,
                "confidence": round(float(self.confidence), 4), "frames": self.frames,
                "residual": None if self.residual is None else round(float(self.residual), 4),
                "why": self.why}


@dataclass
class LagDecision:
    """What the pipeline's `[sync] lag` made of an episode: the shift applied and why."""

    mode: str                 # "estimate" or "fixed"
    shift_ns: int             # subtracted from every tactile timestamp (0 when not applied)
    applied: bool
    reason: str
    estimate: LagEstimate | None = None

    def to_dict(self) -> dict:
        """The sync report's "lag" entry."""
        d = {"mode": self.mode, "lag_ms": self.shift_ns / 1e6 if self.applied else None,
             "applied": self.applied, "reason": self.reason}
        if self.estimate is not None:
            d["estimate"] = self.estimate.to_dict()
            d["confidence"] = round(float(self.estimate.confidence), 4)
        return d


def thumbnail(frame: np.ndarray) -> np.ndarray:
    """(THUMB*THUMB,) float32 grey levels of an HxWx3 uint8 RGB frame (area resize)."""
    import cv2

    grey = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY)
    return cv2.resize(grey, (THUMB, THUMB), interpolation=cv2.INTER_AREA).astype(np.float32).reshape(-1)


def _features(thumbs: np.ndarray) -> np.ndarray:
    """Thumbnails projected on their first COMPONENTS principal components (float64).

    The components come from at most PCA_FRAMES evenly spaced frames, through
    the eigenvectors of their small Gram matrix (cheaper than an SVD of the
    frames, and its cost stays flat in episode length)."""
    x = thumbs.astype(np.float64)
    x -= x.mean(axis=0)
    some = x[np.linspace(0, x.shape[0] - 1, min(x.shape[0], PCA_FRAMES)).round().astype(np.int64)]
    w, v = np.linalg.eigh(some @ some.T)
    top = np.argsort(w)[::-1][:COMPONENTS]
    top = top[w[top] > 1e-9 * max(float(w.max()), 1e-300)]
    comps = some.T @ v[:, top]
    return x @ (comps / np.linalg.norm(comps, axis=0))


def look_alikes(features: np.ndarray, t_s: np.ndarray, exclude_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(N, NEIGHBOURS) nearest frames in feature space, at least `exclude_s` and at most SEARCH_S away in
    time, and the mask of frames that have that many. Blocks of QUERY_BLOCK frames against the frames
    within SEARCH_S of the block: time and memory stay linear in episode length."""
    n = features.shape[0]
    sq = (features ** 2).sum(axis=1)
    k = min(NEIGHBOURS, max(n - 1, 1))
    nb = np.zeros((n, k), dtype=np.int64)
    ok = np.zeros(n, dtype=bool)
    for start in range(0, n, QUERY_BLOCK):
        stop = min(n, start + QUERY_BLOCK)
        lo = int(np.searchsorted(t_s, t_s[start] - SEARCH_S, side="left"))
        hi = int(np.searchsorted(t_s, t_s[stop - 1] + SEARCH_S, side="right"))
        d = sq[start:stop, None] + sq[None, lo:hi] - 2.0 * features[start:stop] @ features[lo:hi].T
        gap = np.abs(t_s[start:stop, None] - t_s[None, lo:hi])
        d[(gap < exclude_s) | (gap > SEARCH_S)] = np.inf
        kk = min(k, hi - lo)
        part = np.argpartition(d, kk - 1, axis=1)[:, :kk] if hi - lo > kk else np.argsort(d, axis=1)[:, :kk]
        found = np.isfinite(np.take_along_axis(d, part, axis=1)).all(axis=1) & (kk == k)
        nb[start:stop, :kk] = part + lo
        ok[start:stop] = found
    return nb, ok


def _contact_at(times_s: np.ndarray, tactile: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Sum over hands of the contact at `times_s` (NaN outside any hand's recorded span)."""
    total = np.zeros(times_s.size)
    for t, c in tactile:
        total += np.interp(times_s, t, c, left=np.nan, right=np.nan)
    return total


def _residuals(lags_s: np.ndarray, t_rgb_s: np.ndarray, tactile, nb: np.ndarray,
               ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual and compared-frame count per lag (NaN residual when the contact is flat or too few frames)."""
    res = np.full(lags_s.size, np.nan)
    used = np.zeros(lags_s.size, dtype=np.int64)
    for j, lag in enumerate(lags_s):
        y = _contact_at(t_rgb_s + lag, tactile)
        finite = np.isfinite(y)
        valid = ok & finite & finite[nb].all(axis=1)
        used[j] = int(valid.sum())
        if used[j] < MIN_FRAMES:
            continue
        var = float(np.var(y[finite]))
        if var <= CONTACT_STD_MIN ** 2:
            continue
        err = y[valid] - y[nb[valid]].mean(axis=1)
        res[j] = float(np.mean(err ** 2)) / var
    return res, used


def _refine(lags_s: np.ndarray, res: np.ndarray, k: int) -> float:
    """Sub-step minimum: the vertex of the parabola through (k-1, k, k+1) when all three are finite."""
    if 0 < k < lags_s.size - 1 and np.isfinite(res[k - 1:k + 2]).all():
        a, b, c = res[k - 1], res[k], res[k + 1]
        den = a - 2 * b + c
        if den > 0:
            return float(lags_s[k] + 0.5 * (a - c) / den * (lags_s[1] - lags_s[0]))
    return float(lags_s[k])


def _too_little(t_rgb_s, thumbs, tactile) -> str:
    """Why the streams cannot be compared at all ("" when they can)."""
    n = t_rgb_s.size
    if n < MIN_FRAMES:
        return f"too short: {n} RGB frames (at least {MIN_FRAMES} needed)"
    if float(thumbs.std(axis=0).max()) < FLAT_VIDEO_MAX:
        return "flat video: the picture does not change"
    inside = _contact_at(t_rgb_s, tactile)
    inside = inside[np.isfinite(inside)]
    if inside.size < MIN_FRAMES:
        return f"too short: {inside.size} RGB frames inside the tactile recording (at least {MIN_FRAMES} needed)"
    if float(inside.std()) < CONTACT_STD_MIN:
        return f"no contact changes: the mean contact stays within {inside.std():.1e} of its average"
    return ""


def estimate_lag(t_rgb_ns, thumbs: np.ndarray, tactile: dict[str, tuple[np.ndarray, np.ndarray]],
                 max_lag_ns: int) -> LagEstimate:
    """Estimate tactile - RGB lag within +-max_lag_ns (see the module docstring).

    `t_rgb_ns` (N,) int64 strictly increasing, `thumbs` (N, THUMB*THUMB) their
    thumbnails; `tactile` hand -> (timestamps ns strictly increasing, mean
    contact per row). Pure: no I/O.
    """
    t_rgb_ns = np.asarray(t_rgb_ns, dtype=np.int64)
    if t_rgb_ns.size == 0:
        return LagEstimate(None, 0.0, "too short: no RGB frame", 0)
    t0 = int(t_rgb_ns[0])
    t_rgb_s = (t_rgb_ns - t0).astype(np.float64) / 1e9
    series = [((np.asarray(t, np.int64) - t0).astype(np.float64) / 1e9, np.asarray(c, np.float64))
              for t, c in tactile.values() if len(t)]
    max_lag_s = max_lag_ns / 1e9
    why = _too_little(t_rgb_s, thumbs, series) if series else "no tactile rows"
    if why:
        return LagEstimate(None, 0.0, why, int(t_rgb_ns.size))
    nb, ok = look_alikes(_features(thumbs), t_rgb_s, max(max_lag_s, MIN_EXCLUDE_S))
    n_steps = max(1, int(round(max_lag_s / LAG_STEP_S)))
    lags = np.linspace(-max_lag_s, max_lag_s, 2 * n_steps + 1)
    res, used = _residuals(lags, t_rgb_s, series, nb, ok)
    if not np.isfinite(res).any():
        return LagEstimate(None, 0.0, f"too short: at most {int(used.max())} frames have look-alike frames "
                           f"more than {max(max_lag_s, MIN_EXCLUDE_S) * 1e3:.0f} ms away (at least "
                           f"{MIN_FRAMES} needed)", int(t_rgb_ns.size))
    k = int(np.nanargmin(res))
    lag_ns = int(round(_refine(lags, res, k) * 1e9))
    confidence = float(np.clip(1.0 - res[k] / np.nanmedian(res), 0.0, 1.0))
    frames = int(used[k])
    if k in (0, lags.size - 1):
        return LagEstimate(lag_ns, 0.0, f"best lag on the edge of the searched range (+-{max_lag_ns / 1e6:g} ms): "
                           f"the true lag may lie beyond it", frames, float(res[k]))
    return LagEstimate(lag_ns, confidence, "", frames, float(res[k]))


# --------------------------------------------------------------------------- one episode, read through its adapter

def time_order(ts) -> np.ndarray:
    """Original indices in time order, exact duplicates after the first removed (as sync.clean_timestamps
    orders a stream, without its warnings: the ingest pass reports those once)."""
    ts = np.asarray(ts, dtype=np.int64)
    order = np.argsort(ts, kind="stable")
    keep = np.ones(order.size, dtype=bool)
    keep[1:] = ts[order][1:] != ts[order][:-1]
    return order[keep]


def _contact_series(streams, hand: str, normaliser, chunk: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps ns, mean normalised live contact) of one hand: time-sorted, duplicates and
    non-finite rows removed (rows are read in file order, `chunk` at a time)."""
    ts = np.asarray(streams.tactile_timestamps_ns[hand])
    contact = np.full(ts.size, np.nan)
    if normaliser.cfg.per_episode and ts.size:    # a baseline chosen by activity sees every row first
        step = float(np.median(np.diff(np.sort(ts)))) if ts.size > 1 else 0.0
        normaliser.fit_episode(np.asarray(streams.read_tactile(hand, np.arange(ts.size)), np.float32),
                               1e9 / step if step > 0 else 30.0)
    for start in range(0, ts.size, chunk):
        rows = np.arange(start, min(ts.size, start + chunk))
        raw = np.asarray(streams.read_tactile(hand, rows), dtype=np.float32)
        if start == 0:
            normaliser.fit_baseline(raw)
        values, finite = normaliser.apply(raw, rows=rows)
        live = values[:, normaliser.live_mask]
        contact[rows[finite]] = live[finite].mean(axis=1)
    order = time_order(ts)
    order = order[np.isfinite(contact[order])]
    return ts[order].astype(np.int64), contact[order]


def _rgb_series(streams) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps ns, thumbnails) of the decoded RGB frames, time-sorted, duplicates removed."""
    thumbs = {int(i): thumbnail(frame) for i, frame in streams.iter_rgb()}
    ts = np.asarray(streams.rgb_timestamps_ns)
    order = np.array([i for i in time_order(ts) if int(i) in thumbs], dtype=np.int64)
    stack = np.stack([thumbs[int(i)] for i in order]) if order.size else np.zeros((0, THUMB * THUMB), np.float32)
    return ts[order].astype(np.int64), stack


def estimate_episode_lag(ref, adapter, params: dict, normalising: NormaliseSettings, sync: SyncConfig,
                         hands: list[str]) -> LagEstimate:
    """Open the episode a second time (the ingest's own pass stays one pass) and estimate its lag.

    Args:
        ref: the planned episode (its layouts resolved: `ref.layout_files`).
        adapter: the source adapter that reads it, with `params` (the pipeline's [adapter.params]).
        normalising: the pipeline's normalisation: contact is normalised as the ingest normalises it.
        sync: the pipeline's [sync] section (the search range `max_lag_ms`).
        hands: the hands whose contact is compared with the video.

    A source that cannot be read here gives a declined estimate naming why; the ingest pass reports it too.
    """
    try:
        with adapter.open(ref, params) as streams:
            tactile = {}
            for h in hands:
                layout = load_layout(ref.layout_files[h])
                tactile[h] = _contact_series(streams, h, Normaliser(normalising.normalise_for(layout), layout))
            t_rgb, thumbs = _rgb_series(streams)
    except Exception as exc:   # noqa: BLE001 (declined, never a failed episode: the main pass decides that)
        return LagEstimate(None, 0.0, f"could not read the episode for the estimate: {type(exc).__name__}: {exc}")
    return estimate_lag(t_rgb, thumbs, tactile, sync.max_lag_ns)


def episode_lag(ref, adapter, params: dict, normalising: NormaliseSettings, sync: SyncConfig,
                hands: list[str]) -> LagDecision | None:
    """What `[sync] lag` says for this episode: None for "none" (nothing recorded, nothing shifted).

    Args: as `estimate_episode_lag`, whose estimate is opened only for `sync.lag = "estimate"`.
    """
    mode = sync.lag
    if isinstance(mode, str) and mode == "none":
        return None
    if not isinstance(mode, str):
        return LagDecision("fixed", int(round(float(mode) * 1e6)), True,
                           f"fixed by the pipeline ([sync] lag = {float(mode):g} ms)")
    est = estimate_episode_lag(ref, adapter, params, normalising, sync, hands)
    if est.why:
        return LagDecision("estimate", 0, False, f"not applied: {est.why}", est)
    if est.confidence < sync.min_confidence:
        return LagDecision("estimate", 0, False, f"not applied: confidence {est.confidence:.2f} below "
                           f"min_confidence {sync.min_confidence:g}", est)
    return LagDecision("estimate", int(est.lag_ns), True,
                       f"applied: confidence {est.confidence:.2f} >= min_confidence {sync.min_confidence:g}", est)


def __getattr__(name: str):
    """An old name of this module, at its new home (htdata/_moved.py MOVED_NAMES), with a DeprecationWarning."""
    return moved_name(__name__, name)
