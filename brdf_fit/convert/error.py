"""The error every conversion reports, written once: the relative RMS error of the reflected
radiance ``f cos(theta_i)`` (unit irradiance from ``wi``) over a geometry and every channel,

    sqrt( sum ((f_src - f) cos_i)^2 / sum (f_src cos_i)^2 ),

the unweighted form of :data:`brdf_fit.selection.ERROR_DEFINITION` (which lives in a higher
layer and also takes the data's weights)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["radiance_error"]


def radiance_error(f_src, f, wi) -> float:
    """The relative RMS radiance error of ``f`` against ``f_src`` (``(N, C)`` or ``(N,)``) on
    directions ``wi`` ``(N, 3)``, in NumPy float64. A source that reflects nothing: 0 when ``f``
    is 0 too, else inf (a relative error of nothing)."""
    f_src = np.asarray(f_src, float)
    f = np.asarray(f, float)
    c = np.asarray(wi, float)[:, 2].reshape((-1,) + (1,) * (f_src.ndim - 1))
    num = float(np.sum(((f_src - f) * c) ** 2))
    den = float(np.sum((f_src * c) ** 2))
    if den == 0.0:
        return 0.0 if num == 0.0 else math.inf
    return math.sqrt(num / den)
