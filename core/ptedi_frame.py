"""P-TEDI's frame side: what one APS frame says about each zone's ``ln Pbar``.

:class:`FrameSideMixin` holds the image computations of :class:`necviz.core.ptedi.PeripheralEstimator`:
``ln Pbar`` per zone from the image alone (Eq. 15, ``g(mean_R Z) - ln T - ln K``, or the mean-log
form: the mean over valid pixels of ``g(Z)``), with the valid and over-exposed fractions the anchor
rule reads (:meth:`~FrameSideMixin.frame_log_irradiance`, and its scalar whole-sensor form from
the frame's digit histogram, :meth:`~FrameSideMixin.digit_histogram_of`), and the saturation bounds a clipped frame still
proves (:meth:`~FrameSideMixin.frame_bounds`). The anchor rule that uses them is
:meth:`PeripheralEstimator.add_frame <necviz.core.ptedi.PeripheralEstimator.add_frame>`.
"""

from __future__ import annotations

import math

import numpy as np

from necviz.core.crf import US_PER_S, CameraResponse
from necviz.core.frames import Frame
from necviz.core.ptedi_kernels import digit_histogram

_DIGITS = np.arange(256, dtype=np.int64)


class FrameSideMixin:
    """The frame-side methods of :class:`~necviz.core.ptedi.PeripheralEstimator` (a mixin: it reads the
    estimator's ``crf``, ``image_form``, ``one_sided_clip``, ``whole``, ``num_zones``, ``sizes`` and zone map)."""

    # what the estimator sets in its __init__ (declared here so the methods type-check)
    crf: CameraResponse
    image_form: str
    one_sided_clip: float
    whole: bool
    num_zones: int
    sizes: np.ndarray
    _zone_flat: np.ndarray
    _in_region: np.ndarray

    def frame_log_irradiance(self, frame: Frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(ln Pbar, valid fraction, over-exposed fraction)`` per zone from the image alone
        (Eq. 15 or the mean-log form)."""
        if self.whole:
            lp, frac, over = self._whole_frame_log_irradiance(frame)
            return np.array([lp]), np.array([frac]), np.array([over])
        z = frame.image.ravel()
        log_tk = math.log(frame.exposure_us / US_PER_S) + math.log(frame.gain)
        zf, inr = self._zone_flat, self._in_region
        valid = (z >= self.crf.valid_min) & (z <= self.crf.valid_max)
        k = self.num_zones
        nvalid = np.bincount(zf[inr & valid], minlength=k).astype(np.float64)
        frac = nvalid / self.sizes
        over = np.bincount(zf[inr & (z > self.crf.valid_max)], minlength=k) / self.sizes
        if self.image_form == "paper":
            mean_z = np.bincount(zf[inr], weights=z[inr].astype(np.float64), minlength=k) / self.sizes
            return np.asarray(self.crf.log_exposure(mean_z), dtype=np.float64) - log_tk, frac, over
        sel = inr & valid
        gsum = np.bincount(zf[sel], weights=self.crf.g[z[sel]], minlength=k)
        with np.errstate(invalid="ignore", divide="ignore"):
            return gsum / nvalid - log_tk, frac, over

    def frame_bounds(self, frame: Frame, log_pbar=None, frac=None, over=None) -> tuple[np.ndarray, np.ndarray]:
        """Per zone, what a frame proves about its ``ln Pbar`` even when too many pixels are clipped:
        ``(lower, upper)`` bounds, NaN where it proves nothing.

        Clipping hides how far beyond the valid range a pixel's irradiance lies, but not on which side.
        With the paper's image form (``g(mean Z)``: the log of the zone's mean exposure), a lower bound
        always exists: count every under-exposed pixel as receiving nothing and every over-exposed one
        as exactly at the top of the valid range, ``ln((Σ_valid E(Z) + N_over E(250)) / N) - ln T K``
        with ``E = exp(g)``; this holds for frames clipped at both ends too. An upper bound exists only
        when (essentially) nothing is over-exposed — at most ``one_sided_clip`` of the zone, a few hot
        pixels — with under-exposed pixels counted at the bottom of the valid range. With the
        ``mean_log`` form a clipped pixel's log is unbounded, so only a frame clipped at one end
        (the other end at most ``one_sided_clip``) bounds it, from that side. O(pixels).
        """
        if log_pbar is None:
            log_pbar, frac, over = self.frame_log_irradiance(frame)
        under = 1.0 - frac - over
        nan = np.full(self.num_zones, np.nan)
        if self.image_form == "mean_log":
            lower = np.where((over > under) & (under <= self.one_sided_clip), log_pbar, nan)
            upper = np.where((under > over) & (over <= self.one_sided_clip), log_pbar, nan)
            return lower, upper
        crf = self.crf
        z = frame.image.ravel()
        log_tk = math.log(frame.exposure_us / US_PER_S) + math.log(frame.gain)
        e_valid = self._valid_exposures(crf)
        if self.whole:
            sums = np.array([float(self.digit_histogram_of(frame)[0] @ e_valid)])
        else:
            inr = self._in_region
            sums = np.bincount(self._zone_flat[inr], weights=e_valid[z[inr]], minlength=self.num_zones)
        e_top, e_bottom = math.exp(crf.g[crf.valid_max]), math.exp(crf.g[crf.valid_min])
        with np.errstate(divide="ignore", invalid="ignore"):
            lower = np.log((sums / self.sizes) + over * e_top) - log_tk
            upper = np.log((sums / self.sizes) + under * e_bottom + over * e_top) - log_tk
        lower = np.where(np.isfinite(lower), lower, nan)
        upper = np.where((over <= self.one_sided_clip) & np.isfinite(upper), upper, nan)
        return lower, upper

    def digit_histogram_of(self, frame: Frame) -> np.ndarray:
        """The frame's whole-image digit histogram (1 x 256 int64,
        :func:`~necviz.core.ptedi_kernels.digit_histogram`), computed once per frame: the anchor, the
        saturation bounds and a controller's metering all read it."""
        hist = self.counted_digit_histogram(frame)
        if hist is None:
            hist = digit_histogram(frame.image.ravel())
            self._hist_memo = (frame.image, hist)
        return hist

    def counted_digit_histogram(self, frame: Frame) -> np.ndarray | None:
        """:meth:`digit_histogram_of` ``frame`` if it was already computed (the whole-sensor anchor does), else
        None: for readers that only want it when it costs nothing (telemetry's over/under-exposed rates)."""
        memo = getattr(self, "_hist_memo", None)
        return memo[1] if memo is not None and memo[0] is frame.image else None

    def _valid_exposures(self, crf) -> np.ndarray:
        """``exp(g(Z))`` for valid digits, 0 for clipped ones (256 values; kept per response curve)."""
        cached = getattr(self, "_e_valid", None)
        if cached is None or cached[0] is not crf:
            d = np.arange(256)
            cached = (crf, np.where((d >= crf.valid_min) & (d <= crf.valid_max), np.exp(crf.g), 0.0))
            self._e_valid = cached
        return cached[1]

    def _whole_frame_log_irradiance(self, frame: Frame) -> tuple[float, float, float]:
        """Scalar :meth:`frame_log_irradiance` for the single whole-sensor zone."""
        crf = self.crf
        z = frame.image.ravel()
        log_tk = math.log(frame.exposure_us / US_PER_S) + math.log(frame.gain)
        if self.image_form == "paper":
            h = self.digit_histogram_of(frame)[0]  # one pass over the image, shared with the bounds and metering
            total = int(h @ _DIGITS)
            nv, no = int(h[crf.valid_min : crf.valid_max + 1].sum()), int(h[crf.valid_max + 1 :].sum())
            mean = total / z.size
            i = min(int(mean), 254)
            g_mean = crf.g[i] + (crf.g[i + 1] - crf.g[i]) * (mean - i)
            return float(g_mean) - log_tk, nv / z.size, no / z.size
        full = np.bincount(z, minlength=256)
        hist = full[crf.valid_min : crf.valid_max + 1]
        nv = int(hist.sum())
        over = int(full[crf.valid_max + 1 :].sum()) / z.size
        if nv == 0:
            # no valid pixel: the clipped mean still bounds the irradiance (see add_frame)
            mean = float(z.mean())
            i = min(int(mean), 254)
            return float(crf.g[i] + (crf.g[i + 1] - crf.g[i]) * (mean - i)) - log_tk, 0.0, over
        return float(np.dot(hist, crf.g[crf.valid_min : crf.valid_max + 1])) / nv - log_tk, nv / z.size, over
