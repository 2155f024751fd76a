"""Validation of concrete parameter values with messages that name the problem.

Traced values (inside ``jit``/``grad``/``vmap``) cannot be inspected and are passed through: the
checks run when a model is built from concrete numbers, which is where user input enters.
"""

from __future__ import annotations

import numpy as np


class ParameterError(ValueError):
    """A model parameter is outside its valid range or has the wrong shape."""


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
