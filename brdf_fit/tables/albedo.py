"""Albedo tables of any registry model: ``E(mu, p1, p2, ...)`` on a grid over the view cosine and
any of the entry's parameters, and the hemispherical average ``E_avg(p1, ...)``.

``E(mu; params) = Int f(wi, wo) cos(theta_i) dwi`` with ``wo = (sqrt(1 - mu^2), 0, mu)`` (the
view azimuth is irrelevant for isotropic models; for anisotropic ones it is the x axis of the
tangent frame), each texel integrated by :func:`brdf_fit.verify.albedo.directional_albedo` (the
rule suited to each lobe: horizon-exact half-vector rule for microfacet lobes, the mirror-lobe
rule for Phong lobes, exact rules for Lambert; docs/quadrature.md). The average is

    E_avg = 2 Int_0^1 E(mu) mu dmu

(Kulla & Conty 2017, "Revisiting Physically Based Shading at Imageworks", the average albedo of
their energy compensation), by Gauss-Legendre in ``mu`` with :data:`N_MU_AVG` nodes (on the exact
integrand, not on the table's grid).

Everything is computed in float64 whatever the global JAX setting, in blocks of texels under one
compiled, vmapped function (one compilation per model, axis set and block size).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit._version import __version__
from brdf_fit.core.quadrature import HALFVECTOR_N_PHI, gauss_legendre_interval
from brdf_fit.core.table import Axis, Table
from brdf_fit.registry import get as registry_get
from brdf_fit.verify.albedo import GENERIC_N_MU, GENERIC_N_PHI, directional_albedo

__all__ = ["N_MU_AVG", "MU_FLOOR", "AxisSpec", "albedo_table", "average_table", "parse_axis"]

#: Gauss-Legendre nodes in ``mu`` for ``E_avg`` (measured on GGX, alpha in [1e-3, 1]: 32 and 64
#: nodes agree to 2e-7; ``E(mu)`` has an ``mu log mu`` term at 0, which limits GL's convergence)
N_MU_AVG = 64
#: a ``mu = 0`` node (endpoint grids) is evaluated at this cosine: the view on the horizon has no
#: solid angle of its own, ``E`` is the limit ``mu -> 0+``, reached linearly in ``mu/alpha`` for
#: microfacet lobes (tables.dfg.MU_LIMIT_REL)
MU_FLOOR = 1e-9
#: texels per compiled call (bounds memory: a block holds BLOCK x 3072-16384 nodes)
BLOCK = 256

#: an axis request: the number of nodes, or ``(n, lo, hi)``
AxisSpec = int | tuple[int, float, float]


def parse_axis(text: str) -> tuple[str, AxisSpec]:
    """``"alpha=64"`` or ``"eta=32:1.0:3.0"`` -> ``("alpha", 64)`` / ``("eta", (32, 1.0, 3.0))``."""
    name, sep, rest = text.partition("=")
    parts = rest.split(":")
    try:
        if not sep or len(parts) not in (1, 3):
            raise ValueError
        n = int(parts[0])
        spec: AxisSpec = n if len(parts) == 1 else (n, float(parts[1]), float(parts[2]))
    except ValueError:
        raise ValueError(f"axis {text!r}: expected NAME=N or NAME=N:LO:HI") from None
    return name.strip(), spec


def _axes(entry, axes: Mapping[str, AxisSpec], centres: bool) -> list[Axis]:
    out = []
    for name, spec in axes.items():
        n, lo, hi = (spec, None, None) if isinstance(spec, int) else spec
        if not isinstance(n, int) or n < (1 if centres else 2):
            raise ValueError(f"axis {name!r}: need at least {1 if centres else 2} nodes, got {n}")
        if name == "mu":
            lo = 0.0 if lo is None else lo
            hi = 1.0 if hi is None else hi
            if not (0.0 <= lo < hi <= 1.0):
                raise ValueError(f"axis 'mu' must lie in [0, 1], got [{lo}, {hi}]")
        else:
            p = entry.param(name)  # unknown names raise with the valid list
            lo = p.lo if lo is None else lo
            hi = p.hi if hi is None else hi
            if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
                raise ValueError(
                    f"axis {name!r}: {entry.name} declares {name} in {p.interval()}; give a "
                    f"finite range as {name}=N:LO:HI")
            if not lo < hi:
                raise ValueError(f"axis {name!r}: need lo < hi, got [{lo}, {hi}]")
            ax = Axis(name, float(lo), float(hi), n, centres)
            # the nodes must be valid parameter values (an open end is never a node of a
            # texel-centre grid; an endpoint grid would evaluate it)
            for v in ax.nodes()[[0, -1]]:
                p.validate(float(v), entry.name)
            out.append(ax)
            continue
        out.append(Axis(name, float(lo), float(hi), n, centres))
    return out


def _evaluator(entry, fixed: dict, names: tuple[str, ...], rule: dict):
    """A jitted, vmapped ``(mu[K], P[K, len(names)]) -> E[K, C]`` in float64."""

    def one(mu, p):
        params = dict(fixed)
        params.update({n: p[i] for i, n in enumerate(names)})
        model = entry.build(**params)
        wo = jnp.stack([jnp.sqrt(jnp.maximum(1.0 - mu * mu, 0.0)), jnp.zeros_like(mu), mu])
        e = directional_albedo(model, wo, **rule)
        return jnp.atleast_1d(e)

    return jax.jit(jax.vmap(one))


def _run(fn, mu, P, progress, block=BLOCK):
    total = mu.size
    out = None
    for s in range(0, total, block):
        m = mu[s:s + block]
        p = P[s:s + block]
        n = m.size
        pad = (block if total > block else max(8, 1 << (n - 1).bit_length())) - n
        m = np.concatenate([m, np.full(pad, 0.5)])
        p = np.concatenate([p, np.repeat(p[-1:], pad, axis=0)])
        e = np.asarray(fn(jnp.asarray(m), jnp.asarray(p)))[:n]
        if out is None:
            out = np.empty((total, e.shape[-1]))
        out[s:s + n] = e
        if progress is not None:
            progress(min(s + block, total), total)
    return out


def _channels(c: int) -> tuple[str, ...]:
    if c == 1:
        return ("E",)
    if c == 3:
        return ("E_R", "E_G", "E_B")
    return tuple(f"E_{k}" for k in range(c))


def albedo_table(model: str, axes: Mapping[str, AxisSpec], params: Mapping | None = None, *,
                 centres: bool = True, error_estimate: bool = True,
                 progress: Callable[[int, int], None] | None = None) -> Table:
    """``E`` of registry entry ``model`` on the grid of ``axes`` (in order; ``"mu"`` must be one
    of them; any other name is a parameter of the entry, over its declared interval unless a
    range is given), the other parameters at ``params`` or the entry's defaults.

    Axes are texel centres by default (``centres=False``: endpoints). The table's channels are
    ``E`` (one channel) or ``E_R, E_G, E_B``. Its metadata holds ``E_avg`` (the average over
    ``mu`` at each node of the other axes, as nested lists, when there are at most 4096) and an
    ``error_estimate``: the largest difference, on a subgrid of up to 8 nodes per axis including
    both ends, against rules with twice the nodes in each direction."""
    entry = registry_get(model)
    if "mu" not in axes:
        raise ValueError("an albedo table needs a 'mu' axis (e.g. mu=64)")
    fixed = {k: v for k, v in (params or {}).items()}
    for k in fixed:
        entry.param(k)
        if k in axes:
            raise ValueError(f"parameter {k!r} is both an axis and fixed")
    grid = _axes(entry, axes, centres)
    names = tuple(a.name for a in grid if a.name != "mu")
    rule = {"n_phi": HALFVECTOR_N_PHI, "generic": (GENERIC_N_MU, GENERIC_N_PHI)}
    t0 = time.perf_counter()
    with jax.enable_x64(True):
        fixed64 = {k: jnp.asarray(v, jnp.float64) for k, v in fixed.items()}
        fn = _evaluator(entry, fixed64, names, rule)
        nodes = np.meshgrid(*(a.nodes() for a in grid), indexing="ij")
        flat = {a.name: g.ravel() for a, g in zip(grid, nodes, strict=True)}
        mu = np.maximum(flat["mu"], MU_FLOOR)
        P = np.stack([flat[n] for n in names], -1) if names else np.zeros((mu.size, 0))
        E = _run(fn, mu, P, progress)
        seconds = time.perf_counter() - t0
        meta = {
            "kind": "albedo", "model": entry.name, "params": {k: np.asarray(v).tolist()
                                                            for k, v in fixed.items()},
            "layout": {"centres": centres, "image_origin": "top"},
            "quadrature": "verify.albedo.directional_albedo defaults (per lobe), float64",
            "limits": {"mu=0": f"evaluated at mu={MU_FLOOR}"},
            "seconds": round(seconds, 3), "brdf_fit_version": __version__,
        }
        if error_estimate:
            idx = [np.unique(np.linspace(0, a.n - 1, min(a.n, 8)).round().astype(int))
                   for a in grid]
            sub = np.meshgrid(*idx, indexing="ij")
            sel = np.ravel_multi_index([s.ravel() for s in sub], tuple(a.n for a in grid))
            fine = _evaluator(entry, fixed64, names,
                              {"n_theta": 96, "n_phi": 2 * HALFVECTOR_N_PHI,
                               "generic": (2 * GENERIC_N_MU, 2 * GENERIC_N_PHI)})
            E2 = _run(fine, mu[sel], P[sel], None)
            meta["error_estimate"] = {
                "max_abs": float(np.abs(E2 - E[sel]).max()),
                "method": f"against rules with twice the nodes on {sel.size} texels "
                          "(up to 8 per axis, ends included)",
            }
        other = [a for a in grid if a.name != "mu"]
        if int(np.prod([a.n for a in other])) <= 4096:
            avg = _average(fn, other, None)
            meta["E_avg"] = {"axes": [a.to_dict() for a in other],
                             "values": avg.reshape(tuple(a.n for a in other) + (-1,)).tolist()}
    shape = tuple(a.n for a in grid) + (E.shape[-1],)
    return Table(E.reshape(shape), grid, _channels(E.shape[-1]), meta)


def _average(fn, other: list[Axis], progress):
    """``E_avg`` at every node of ``other`` (flattened, shape ``(M, C)``), GL in mu."""
    x, w = gauss_legendre_interval(N_MU_AVG, 0.0, 1.0)
    nodes = np.meshgrid(*(a.nodes() for a in other), indexing="ij") if other else []
    P = np.stack([g.ravel() for g in nodes], -1) if other else np.zeros((1, 0))
    M = P.shape[0]
    mu = np.tile(x, M)
    PP = np.repeat(P, x.size, axis=0)
    E = _run(fn, mu, PP, progress).reshape(M, x.size, -1)
    return 2.0 * np.einsum("mkc,k->mc", E, w * x)


def average_table(model: str, axes: Mapping[str, AxisSpec], params: Mapping | None = None, *,
                  centres: bool = True, progress=None) -> Table:
    """``E_avg = 2 Int E(mu) mu dmu`` of registry entry ``model`` on the grid of ``axes`` (the
    entry's parameters; no ``mu`` axis), channels ``E_avg`` (or ``E_avg_R, ...``)."""
    entry = registry_get(model)
    if "mu" in axes:
        raise ValueError("E_avg is averaged over mu: give only parameter axes")
    fixed = dict(params or {})
    for k in fixed:
        entry.param(k)
    grid = _axes(entry, axes, centres)
    names = tuple(a.name for a in grid)
    t0 = time.perf_counter()
    with jax.enable_x64(True):
        fixed64 = {k: jnp.asarray(v, jnp.float64) for k, v in fixed.items()}
        fn = _evaluator(entry, fixed64, names,
                        {"n_phi": HALFVECTOR_N_PHI, "generic": (GENERIC_N_MU, GENERIC_N_PHI)})
        avg = _average(fn, grid, progress)
    ch = tuple(c.replace("E", "E_avg", 1) for c in _channels(avg.shape[-1]))
    meta = {"kind": "E_avg", "model": entry.name,
            "params": {k: np.asarray(v).tolist() for k, v in fixed.items()},
            "layout": {"centres": centres, "image_origin": "top"},
            "quadrature": f"Gauss-Legendre in mu, {N_MU_AVG} nodes, of directional_albedo",
            "seconds": round(time.perf_counter() - t0, 3), "brdf_fit_version": __version__}
    return Table(avg.reshape(tuple(a.n for a in grid) + (-1,)), grid, ch, meta)
