"""The error of a fitted model on measured data, in the measures published fits report.

Every measure is an integral over pairs of directions, estimated from the samples with the
solid angle each stands for (:func:`measure_weights`), over every channel together:

* ``rel_rms``: this package's relative RMS radiance error (:mod:`brdf_fit.convert.error`,
  written there for conversions; the same formula with the measure weights),
  ``sqrt( sum w ((f - f') cos_i)^2 / sum w (f cos_i)^2 )``.
* ``ngan2005``: Ngan, Durand & Matusik, "Experimental analysis of BRDF models", EGSR 2005:
  the cosine-weighted L2 error ``sqrt( sum w ((f - f') cos_i)^2 / sum w )`` over the pairs
  with both zenith angles below :data:`NGAN_MAX_ZENITH_DEG`.
* ``low2012_e1``: Löw, Kronander, Ynnerman & Unger, "BRDF models for accurate and efficient
  rendering of glossy surfaces", ACM TOG 31(1), 2012, E1: the mean of ``((f - f') cos_i)^2``.
* ``low2012_e2``: the same paper's E2, the mean of ``(ln(1 + f cos_i) - ln(1 + f' cos_i))^2``
  (the residual of this package's default ``log`` metric, squared).

``f`` is the data, ``f'`` the model, ``cos_i = wi.z`` (``wi`` toward the light), sums over
samples and channels, means weighted by ``w`` over samples (channels summed).

Sources, and what is not verified: neither paper's text could be read while this was
written, so these forms follow the reference notes of the project (``shared/reference/
formats.md``, 1.2b, marked "from memory, verify") as two public readings confirm them: Sun,
Jensen & Ramamoorthi, ACM TOG 37(6) 2018, eq. 4 (Ngan's measure: the squared cosine-weighted
difference times "the solid angle for each MERL measurement"), and the bsdfbenchmark/bbm
project's loss functions (``include/loss/cosine_weighted_l2.h`` ``lowL2_error`` and
``cosine_weighted_log.h`` ``lowLog_error``: the channels summed, each sample weighted by its
solid-angle Jacobian, averaged). The 80 degree cut of Ngan's and the normalisation of E1 and E2
(a weighted mean here, so that values do not grow with the number of samples) are the least
certain parts; the docs say so.

**Measure weights.** A MERL file's bins are not equal in solid angle: theta_h is binned on a
square-root scale. With the change of variables of Rusinkiewicz ("A new change of variables for
efficient BRDF representation", EGWR 1998), ``dw_i dw_o = 4 cos(theta_d) dw_h dw_d``, so a bin
at (theta_h, theta_d, phi_d) stands for ``4 cos(theta_d) sin(theta_h) sin(theta_d) dtheta_h
dtheta_d dphi_d dphi_h``, and the width of bin i of theta_h is ``(pi/2)(2i + 1)/90^2``, which at
the bin's centre is proportional to ``sqrt(theta_h)``. Other data carry their weights
(``GonioData.weight``: 1 each unless the file gave them).
"""

from __future__ import annotations

import math

import numpy as np

from brdf_fit.data import GonioData
from brdf_fit.io.merl import half_diff_angles
from brdf_fit.models._base import evaluate

__all__ = ["ERRORS", "NGAN_MAX_ZENITH_DEG", "measure_weights", "errors_of_values",
           "model_errors", "EVAL_CHUNK"]

#: the measures, name -> definition (the table's columns, in this order)
ERRORS = {
    "rel_rms": "sqrt(sum w ((f - f') cos_i)^2 / sum w (f cos_i)^2): relative RMS radiance error",
    "ngan2005": "sqrt(sum w ((f - f') cos_i)^2 / sum w), theta_i, theta_o < 80 deg "
                "(Ngan et al., EGSR 2005)",
    "low2012_e1": "sum w ((f - f') cos_i)^2 / sum w (Löw et al., TOG 2012, E1)",
    "low2012_e2": "sum w (ln(1 + f cos_i) - ln(1 + f' cos_i))^2 / sum w (Löw et al., TOG 2012, E2)",
}
#: zenith cut of Ngan et al.'s measure, both directions (reference notes; see the module docstring)
NGAN_MAX_ZENITH_DEG = 80.0
#: direction pairs per compiled evaluation of a model over a file (memory flat in the file)
EVAL_CHUNK = 65536


def measure_weights(data: GonioData) -> np.ndarray:
    """``(N,)`` the solid-angle weight of each sample (module docstring): a MERL file's bin
    measure up to a constant (``metadata["format"] == "merl"``), else the data's own weights
    (their mean over channels)."""
    if (data.metadata or {}).get("format") == "merl":
        theta_h, theta_d, _ = half_diff_angles(data.wi, data.wo)
        return np.cos(theta_d) * np.sin(theta_h) * np.sin(theta_d) * np.sqrt(theta_h)
    w = np.asarray(data.weight, float)
    return w.mean(-1) if w.ndim == 2 else w


def errors_of_values(f_data, f_model, wi, wo, w) -> dict[str, float]:
    """Every measure of :data:`ERRORS` for data values ``f_data`` and model values ``f_model``
    (``(N, C)``) at ``wi``, ``wo`` (``(N, 3)``) with sample weights ``w`` (``(N,)``)."""
    f = np.asarray(f_data, float)
    g = np.asarray(f_model, float)
    f = f[:, None] if f.ndim == 1 else f
    g = np.broadcast_to(g[:, None] if g.ndim == 1 else g, f.shape)
    c = np.asarray(wi, float)[:, 2:3]
    w = np.asarray(w, float)
    d2 = np.sum(((f - g) * c) ** 2, axis=1)
    sw = float(np.sum(w))
    cut = math.cos(math.radians(NGAN_MAX_ZENITH_DEG))
    keep = (np.asarray(wi)[:, 2] > cut) & (np.asarray(wo)[:, 2] > cut)
    sw_cut = float(np.sum(w[keep]))
    den = float(np.sum(w * np.sum((f * c) ** 2, axis=1)))
    log2 = np.sum((np.log1p(np.maximum(f * c, 0.0)) - np.log1p(np.maximum(g * c, 0.0))) ** 2,
                  axis=1)
    nan = float("nan")
    return {
        "rel_rms": math.sqrt(float(np.sum(w * d2)) / den) if den > 0 else nan,
        "ngan2005": math.sqrt(float(np.sum(w[keep] * d2[keep])) / sw_cut) if sw_cut > 0 else nan,
        "low2012_e1": float(np.sum(w * d2)) / sw if sw > 0 else nan,
        "low2012_e2": float(np.sum(w * log2)) / sw if sw > 0 else nan,
    }


def model_values(model, wi, wo) -> np.ndarray:
    """``model.eval`` at every pair, in chunks of :data:`EVAL_CHUNK` through one compiled
    program (the last chunk padded to the same shape with normal-incidence pairs)."""
    n = wi.shape[0]
    out = []
    for s in range(0, n, EVAL_CHUNK):
        a, b = wi[s:s + EVAL_CHUNK], wo[s:s + EVAL_CHUNK]
        m = a.shape[0]
        if m < EVAL_CHUNK and n > EVAL_CHUNK:
            pad = np.tile([0.0, 0.0, 1.0], (EVAL_CHUNK - m, 1))
            a, b = np.concatenate([a, pad]), np.concatenate([b, pad])
        v = np.asarray(evaluate(model, a, b))[:m]
        out.append(v[:, None] if v.ndim == 1 else v)
    return np.concatenate(out) if out else np.zeros((0, 1))


def model_errors(model, data: GonioData) -> dict[str, float]:
    """Every measure of :data:`ERRORS` of a built ``model`` on ``data``."""
    return errors_of_values(data.value, model_values(model, data.wi, data.wo), data.wi,
                            data.wo, measure_weights(data))
