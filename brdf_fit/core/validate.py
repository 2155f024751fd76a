"""Validation of concrete parameter values with messages that name the problem.

Traced values (inside ``jit``/``grad``/``vmap``) cannot be inspected and are passed through: the
checks run when a model is built from concrete numbers, which is where user input enters.
"""

from __future__ import annotations

import numpy as np


class PrecisionWarning(UserWarning):
    """A value was changed for the numerics (clamped, e.g. a microfacet ``alpha`` below
    ``ALPHA_MIN``): the result is that of the changed value, and the warning says so."""


class ParameterError(ValueError):
    """A model parameter is outside its valid range or has the wrong shape."""


class FitError(ValueError):
    """A fit request that cannot be honoured (unknown parameter, bad option); raised by the
    fitting layer (:mod:`brdf_fit.fitting.problem` re-exports it)."""


def concrete(value):
    """``value`` as a NumPy array, or None if it is a tracer (not inspectable)."""
    try:
        return np.asarray(value)
    except Exception:  # jax.errors.TracerArrayConversionError and friends
        return None


def check_param(
    name,
    value,
    lo=None,
    hi=None,
    lo_open=False,
    hi_open=False,
    owner: str | None = None,
):
    """Raise :class:`ParameterError` if a concrete ``value`` leaves ``[lo, hi]`` (ends open as
    requested) or is not finite."""
    v = concrete(value)
    if v is None or v.dtype == object:
        return
    who = f"{owner}: " if owner else ""
    if not np.all(np.isfinite(v)):
        raise ParameterError(f"{who}parameter {name!r} must be finite, got {v.tolist()}")
    if lo is not None:
        bad = v <= lo if lo_open else v < lo
        if np.any(bad):
            rel = ">" if lo_open else ">="
            raise ParameterError(f"{who}parameter {name!r} must be {rel} {lo}, got {v.tolist()}")
    if hi is not None:
        bad = v >= hi if hi_open else v > hi
        if np.any(bad):
            rel = "<" if hi_open else "<="
            raise ParameterError(f"{who}parameter {name!r} must be {rel} {hi}, got {v.tolist()}")


def check_scalar(name, value, owner: str):
    """Raise :class:`ParameterError` if a concrete ``value`` is not a scalar (geometric
    parameters, e.g. widths and exponents, carry no channel axis)."""
    v = concrete(value)
    if v is not None and v.dtype != object and v.ndim != 0:
        raise ParameterError(f"{owner}: parameter {name!r} must be a scalar, got shape {v.shape}")


def check_sum_at_most_one(a, b, label: str, owner: str, why: str = "energy conservation"):
    """Raise :class:`ParameterError` if concrete ``a + b`` exceeds 1 in some channel (``label``
    names the sum in the message, e.g. ``"rho_d + rho_s"``)."""
    d, s = concrete(a), concrete(b)
    if d is not None and s is not None and d.dtype != object and s.dtype != object:
        tot = np.asarray(d, dtype=float) + np.asarray(s, dtype=float)
        if np.any(tot > 1.0):
            raise ParameterError(
                f"{owner}: {label} must be <= 1 in every channel ({why}), got {label} = "
                f"{tot.tolist()}"
            )
