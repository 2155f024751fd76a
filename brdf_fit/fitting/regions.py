"""Where a fit misses: the ratio of a fitted model to its data summarised by region of the
measurement geometry, so that a user sees what a model leaves out (a grazing rise, a
retro-reflective lobe, the peak's shape) before choosing a bigger one (issue 40).

The regions partition the sample pairs by the half and difference angles of Rusinkiewicz
(1998, "A new change of variables for efficient BRDF representation", Eurographics Workshop
on Rendering, sec. 3): ``theta_h`` is the half vector's zenith, ``theta_d`` the angle between
``wi`` and the half vector (half the angle between ``wi`` and ``wo``). In the order they claim
a sample:

- ``grazing``: either direction at or beyond :data:`GRAZING_DEG` from the normal (Fresnel's
  rise and shadowing-masking act there);
- ``specular peak``: ``theta_h`` below :data:`PEAK_DEG` (around the mirror direction);
- ``retro-reflection``: ``theta_d`` below :data:`RETRO_DEG` (``wo`` within twice that of
  ``wi``: back toward the light);
- ``off-specular``: the rest.

The angles are fixed, not scaled to a fitted lobe's width, so that two models fitted to one
file are summarised over the same samples. Per region the summary gives the samples (their
count and share) and the log ratio ``ln((model + floor) / (data + floor))`` over its samples
and channels: its rms (a relative rms for small misfits) and its mean as a factor,
``exp(mean) - 1`` (the model reads that much high, or low when negative). ``floor`` is the
fit's own (:data:`~brdf_fit.fitting.problem.RELATIVE_FLOOR` of the largest datum), so a dark
tail's noise does not dominate. The summary is independent of the metric the fit minimised.
"""

from __future__ import annotations

import numpy as np

from brdf_fit.fitting.problem import DATA_SCALE_FLOOR, RELATIVE_FLOOR

__all__ = ["GRAZING_DEG", "PEAK_DEG", "REGIONS", "RETRO_DEG", "region_index",
           "residuals_by_region"]

#: region names, in the order a sample is claimed (the first that matches)
REGIONS = ("grazing", "specular peak", "retro-reflection", "off-specular")
#: zenith angle (degrees) of either direction from which a sample is grazing
GRAZING_DEG = 75.0
#: half-vector zenith (degrees) below which a sample is in the specular peak
PEAK_DEG = 10.0
#: difference angle (degrees) below which a sample looks back toward the light
RETRO_DEG = 10.0
#: sample pairs per model evaluation: one compiled program per model and channel count,
#: whatever the data's size (the last block is padded with normal-incidence pairs)
EVAL_BLOCK = 65536


def region_index(wi, wo) -> np.ndarray:
    """The index into :data:`REGIONS` of each pair (``(n, 3)`` unit vectors, z the normal)."""
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    h = wi + wo
    h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), np.finfo(float).tiny)
    theta_h = np.degrees(np.arccos(np.clip(h[:, 2], -1.0, 1.0)))
    theta_d = np.degrees(np.arccos(np.clip(np.sum(wi * h, axis=-1), -1.0, 1.0)))
    grazing = np.cos(np.radians(GRAZING_DEG))
    idx = np.full(len(wi), REGIONS.index("off-specular"), np.int8)
    idx[theta_d < RETRO_DEG] = REGIONS.index("retro-reflection")
    idx[theta_h < PEAK_DEG] = REGIONS.index("specular peak")
    idx[(wi[:, 2] <= grazing) | (wo[:, 2] <= grazing)] = REGIONS.index("grazing")
    return idx


def _predict(model, wi, wo, n_channels: int) -> np.ndarray:
    """``model.eval`` at every pair, :data:`EVAL_BLOCK` pairs per call, as ``(n, n_channels)``."""
    import jax.numpy as jnp

    n = len(wi)
    out = np.empty((n, n_channels))
    dtype = jnp.zeros(()).dtype  # the process's float (float64 under jax_enable_x64)
    normal = np.array([0.0, 0.0, 1.0])
    for lo in range(0, n, EVAL_BLOCK):
        hi = min(lo + EVAL_BLOCK, n)
        a, b = wi[lo:hi], wo[lo:hi]
        if hi - lo < EVAL_BLOCK:
            pad = np.broadcast_to(normal, (EVAL_BLOCK - (hi - lo), 3))
            a, b = np.concatenate([a, pad]), np.concatenate([b, pad])
        v = np.asarray(model.eval(jnp.asarray(a, dtype), jnp.asarray(b, dtype)), float)
        v = v.reshape(EVAL_BLOCK, -1)[: hi - lo]
        out[lo:hi] = np.broadcast_to(v, (hi - lo, n_channels))
    return out


def residuals_by_region(model, wi, wo, values) -> list[dict]:
    """One row per region of :data:`REGIONS` (in that order) for ``model`` (a built model)
    against ``values`` (``(n,)`` or ``(n, C)``) at pairs ``wi``, ``wo``: ``region``,
    ``samples``, ``share`` (of all samples), ``rms_log_ratio``, ``mean_factor`` (``exp`` of the
    mean log ratio, minus 1); NaN for the statistics of an empty region. Non-finite data are
    left out."""
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    f = np.asarray(values, float)
    f = f.reshape(len(wi), -1)
    m = _predict(model, wi, wo, f.shape[1])
    floor = RELATIVE_FLOOR * max(float(np.nanmax(np.abs(f))) if f.size else 0.0,
                                 DATA_SCALE_FLOOR)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.log((m + floor) / (f + floor))
    ok = np.isfinite(ratio)
    idx = region_index(wi, wo)
    rows = []
    for k, name in enumerate(REGIONS):
        r = ratio[idx == k][ok[idx == k]]
        n = int(np.sum(idx == k))
        rows.append({
            "region": name, "samples": n, "share": n / max(len(wi), 1),
            "rms_log_ratio": float(np.sqrt(np.mean(r**2))) if r.size else float("nan"),
            "mean_factor": float(np.expm1(np.mean(r))) if r.size else float("nan"),
        })
    return rows
