"""float32 against float64 over every parameter's whole declared interval, for every registry
entry (issue 16, defect 11: HTSG was finite but wrong in float32 for large sigma0, which the
"finite at the extremes" checks cannot see).

For each entry one batch holds, for every parameter in turn, a sweep of that parameter over its
interval (the others at their defaults; a channel parameter sets all channels): closed finite
ends themselves, open ends approached to 1e-6 of the interval, infinite ends by decades
1e-6 .. 1e6 (:func:`sweep`). ``eval`` runs on a fixed set of direction pairs (normal,
~45 degrees (cos 0.7, see COS_45) and grazing cos = 1e-3, in the plane of incidence on both
sides and across it) in float64 and in float32 (the model built in float64, cast with
:func:`brdf_fit.astype` as in ``test_models.py::test_float32_matches_float64``), one jitted
``vmap`` per entry and precision.

Inputs are rounded to float32 first (parameters and directions), so the float64 reference is
the exact value at the very inputs float32 sees: the difference measures only the rounding
inside the model.

Tolerance ``|f32 - f64| <= RTOL |f64| + ATOL_REL peak + ATOL`` (``peak``: the largest float64
value of the same parameter set over all pairs): RTOL = 1e-3 is ~8000 float32 ulp (eps =
1.19e-7). A well-conditioned closed-form BRDF loses a few tens of ulp (measured: <= 2e-5 for
HTSG after the fix, test_models' contract uses 2e-4 at default parameters); 1e-3 still flags
anything that is wrong in the third digit, which is what a float32 fit would notice. ATOL_REL =
1e-7 (~1 ulp of the peak): where a value is a difference of terms of the size of the lobe's
peak (e.g. a cosine that vanishes, like Phong's cos_alpha at the lobe's edge, where the float32
dot product leaves ~1e-8 instead of 0: measured 6.4e-9 at exponent 1), its absolute error is
an ulp of the peak, not of itself; measured: every entry passes with 1e-9 except the two
listed in KNOWN_F32_FAILURES. ATOL = 1e-30: float32's normal range ends at 1.2e-38 and XLA's
CPU backend flushes subnormals, so values (or intermediate products) below ~1e-30 may
legitimately flush to zero; a BRDF value that small is zero for every purpose.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import dir_from_cos

from brdf_fit import astype, registry

RTOL = 1e-3
ATOL_REL = 1e-7
ATOL = 1e-30
#: "45 degrees": cos = 0.7 (45.6 degrees), not sqrt(1/2): at exactly 45 degrees wi = wo puts
#: Phong's reflected direction exactly on the edge of its lobe (cos_alpha = 0), where cos^0 (the
#: exponent's closed end) jumps from 1 to 0 and any rounding decides the side
COS_45 = 0.7
#: decades standing in for an infinite end (and for the approach to an open end at 0)
DECADES = 10.0 ** np.arange(-6, 7, 2)  # 1e-6, 1e-4, ..., 1e6 (7 values)
#: fractions of a finite interval [lo, hi]
FRACTIONS = np.array([0.0, 1e-6, 1e-3, 0.1, 0.5, 0.9, 1 - 1e-3, 1 - 1e-6, 1.0])

#: entries whose float32 evaluation disagrees with float64 somewhere in an interval, with the
#: measured discrepancy (the largest |f32 - f64| over the tolerance, > 1, in the sweep)
#: (none: phong-energy-normalized was the incomplete beta's prefactor near x = 1, fixed in
#: core/special.py; poulin-fournier was its closed-form diffuse integral and occlusion limit,
#: both differences of nearly equal terms at grazing, rewritten in models/poulin_fournier.py)
KNOWN_F32_FAILURES: dict[str, str] = {}


def sweep(p):
    """Values of the parameter ``p`` (a :class:`~brdf_fit.core.params.Param`) covering its
    interval, rounded to float32-representable numbers."""
    lo, hi = p.lo, p.hi
    if lo is None and hi is None:
        v = np.concatenate([-DECADES[::-1], [0.0], DECADES])
    elif hi is None:
        v = lo + DECADES if p.lo_open else np.concatenate([[lo], lo + DECADES])
    elif lo is None:
        v = hi - DECADES if p.hi_open else np.concatenate([[hi], hi - DECADES])
    else:
        q = FRACTIONS
        if p.lo_open:
            q = q[q > 0]
        if p.hi_open:
            q = q[q < 1]
        v = lo + (hi - lo) * q
        v = np.where(q == 1.0, hi, v)  # the closed end itself, not lo + (hi - lo) * 1
    v = np.asarray(v, np.float32).astype(float)
    # rounding to float32 must not leave the interval (e.g. 1 - 1e-6 stays < 1)
    ok = np.ones(v.shape, bool)
    if lo is not None:
        ok &= (v > lo) if p.lo_open else (v >= lo)
    if hi is not None:
        ok &= (v < hi) if p.hi_open else (v <= hi)
    return np.unique(v[ok])


def batch(entry):
    """``(params, labels)``: a dict of stacked parameter arrays (every parameter's sweep in
    turn, the others at their defaults) and a ``(name, value)`` label per row."""
    d = {k: np.asarray(v, float) for k, v in entry.defaults().items()}
    rows, labels = [], []
    for p in entry.params:
        for v in sweep(p):
            row = dict(d)
            row[p.name] = np.full_like(d[p.name], v)
            rows.append(row)
            labels.append((p.name, float(v)))
    params = {k: np.stack([r[k] for r in rows]).astype(np.float32).astype(float) for k in d}
    return params, labels


def direction_pairs():
    cos_phi = [(1.0, 0.0)] + [(c, ph) for c in (COS_45, 1e-3)
                              for ph in (0.0, 0.5 * math.pi, math.pi)]
    dirs = np.array([dir_from_cos(c, ph) for c, ph in cos_phi])
    wi = np.repeat(dirs, len(dirs), 0)
    wo = np.tile(dirs, (len(dirs), 1))
    # float32-representable: the float64 reference sees exactly the float32 inputs
    return (np.asarray(wi, np.float32).astype(float), np.asarray(wo, np.float32).astype(float))


def evaluate(entry, params, wi, wo):
    """``eval`` for every row of ``params`` in float64 and float32 (NumPy float64 arrays)."""

    def one(p, wi, wo, dtype):
        m = entry.build(**p)
        if dtype == jnp.float32:
            m = astype(m, jnp.float32)
        return m.eval(wi.astype(dtype), wo.astype(dtype))

    f = jax.jit(jax.vmap(one, in_axes=(0, None, None, None)), static_argnums=3)
    p64 = {k: jnp.asarray(v) for k, v in params.items()}
    v64 = f(p64, jnp.asarray(wi), jnp.asarray(wo), jnp.float64)
    v32 = f(p64, jnp.asarray(wi), jnp.asarray(wo), jnp.float32)
    assert v32.dtype == jnp.float32
    return np.asarray(v64, float), np.asarray(v32, float)


def worst(v64, v32, labels):
    """The largest ``|f32 - f64|/(RTOL |f64| + ATOL)`` per parameter, with the row's label."""
    n = len(labels)
    scale = np.max(np.abs(v64).reshape(n, -1), axis=1).reshape((n,) + (1,) * (v64.ndim - 1))
    err = np.abs(v32 - v64) / (RTOL * np.abs(v64) + ATOL_REL * scale + ATOL)
    err = np.where(np.isfinite(v64) & ~np.isfinite(v32), np.inf, err)
    per_row = np.max(err.reshape(n, -1), axis=1)
    out = {}
    for (name, value), e, i in zip(labels, per_row, range(len(labels)), strict=True):
        if name not in out or e > out[name][0]:
            out[name] = (float(e), value, i)
    return out


NON_DELTA = [e for e in registry.entries() if "delta" not in e.tags]


def _cases():
    for e in NON_DELTA:
        if e.name in KNOWN_F32_FAILURES:
            yield pytest.param(e, id=e.name, marks=pytest.mark.xfail(
                strict=True, reason=f"measured: {KNOWN_F32_FAILURES[e.name]}"))
        else:
            yield pytest.param(e, id=e.name)


@pytest.mark.parametrize("entry", list(_cases()))
def test_float32_matches_float64_over_intervals(entry):
    params, labels = batch(entry)
    wi, wo = direction_pairs()
    v64, v32 = evaluate(entry, params, wi, wo)
    assert np.all(np.isfinite(v64)), "float64 reference not finite"
    bad = {k: v for k, v in worst(v64, v32, labels).items() if not v[0] <= 1.0}
    msgs = []
    for name, (e, value, i) in bad.items():
        r = np.abs(v32[i] - v64[i]).ravel()
        j = int(np.nanargmax(np.where(np.isfinite(r), r, np.inf)))
        msgs.append(f"{name}={value:g}: {e:.3g} x tolerance (f64 {v64[i].ravel()[j]:.6g}, "
                    f"f32 {v32[i].ravel()[j]:.6g})")
    assert not bad, f"{entry.name}: " + "; ".join(msgs)
