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
compiled, vmapped function (one compilation per model, axis set and block size), streamed on
every core (:mod:`brdf_fit.tables._stream`): live memory is a few blocks whatever the table's
size (measured for a 64^3 table in benchmarks/results/tables.md).

**Channel axes.** An axis over a parameter that the entry declares with channels (``eta`` of a
dielectric Fresnel, ``f0``, ``rho``) is computed as the model's channels, when the model's other
parameters give one channel: the model is built with the whole axis as its channel vector, so
each ``(mu, other parameters)`` texel builds its quadrature rule and evaluates the
channel-independent factors (``D``, ``G``) once for all the axis's values. This is exact, not an
approximation: a channel parameter cannot change the rule (one rule serves a lobe's channels,
:func:`brdf_fit.verify.albedo.directional_albedo` refuses anything else), so each channel is
integrated by the same rule as the scalar model with that value (tests/tables checks the two
paths agree to rounding). For ``E(mu, alpha, eta)`` of ``cook-torrance`` at 64^3 this divides the
rule constructions and the ``D G`` evaluations by 64.
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
from brdf_fit.tables._stream import run_blocks
from brdf_fit.verify.albedo import GENERIC_N_MU, GENERIC_N_PHI, directional_albedo

__all__ = ["N_MU_AVG", "MU_FLOOR", "AxisSpec", "albedo_table", "average_table", "parse_axis"]

#: Gauss-Legendre nodes in ``mu`` for ``E_avg`` (measured on GGX, alpha in [1e-3, 1]: 32 and 64
#: nodes agree to 2e-7; ``E(mu)`` has an ``mu log mu`` term at 0, which limits GL's convergence)
N_MU_AVG = 64
#: a ``mu = 0`` node (endpoint grids) is evaluated at this cosine: the view on the horizon has no
#: solid angle of its own, ``E`` is the limit ``mu -> 0+``, reached linearly in ``mu/alpha`` for
#: microfacet lobes (tables.dfg.MU_LIMIT_REL)
MU_FLOOR = 1e-9
#: texel-channels per compiled call: a block holds ``BLOCK / channels`` texels (at least
#: :data:`MIN_BLOCK`) x 3072-16384 nodes x channels. Measured (2 cores, load 2.5, table and
#: E_avg, best of 2): ``cook-torrance`` 32^3 (eta as 32 channels) 2.52 / 2.58 / 2.33 / 4.45 s
#: and ``ggx`` 64 x 64 2.88 / 2.87 / 2.10 / 2.05 s for 16 / 64 / 256 / 1024
BLOCK = 256
#: the fewest texels per compiled call
MIN_BLOCK = 2

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


def _run(fn, mu, P, progress, block=None, channels: int = 1, offset: int = 0,
         grand_total: int | None = None):
    """``fn`` over texels ``(mu[k], P[k])``, streamed in blocks on every core; ``(K, C)``.
    ``progress(done, total)`` counts table entries (texels x ``channels``), from ``offset`` of
    ``grand_total`` (default: this run's entries)."""
    total = mu.size
    if progress is not None:
        grand = total * channels if grand_total is None else grand_total
        report = progress

        def progress(done, _total):
            report(offset + done * channels, grand)

    if block is None:
        block = max(MIN_BLOCK, BLOCK // max(1, channels))
    width = block if total > block else max(MIN_BLOCK, 1 << max(total - 1, 0).bit_length())
    out: list = [None]

    def compute(start: int, stop: int) -> None:
        m = mu[start:stop]
        p = P[start:stop]
        n = m.size
        pad = width - n
        m = np.concatenate([m, np.full(pad, 0.5)])
        p = np.concatenate([p, np.repeat(p[-1:], pad, axis=0)])
        e = np.asarray(fn(jnp.asarray(m), jnp.asarray(p)))[:n]
        if out[0] is None:  # the first block runs alone (run_blocks), so this is not a race
            out[0] = np.empty((total, e.shape[-1]))
        out[0][start:stop] = e

    run_blocks(compute, total, width, progress=progress)
    return out[0]


def _channel_axis(entry, grid: list, fixed64: dict, names: tuple[str, ...], rule: dict,
                  vectorise: bool) -> int | None:
    """Index in ``grid`` of the axis to compute as the model's channels (module docstring), or
    None: the last axis over a parameter declared with channels, when the model built with
    that parameter scalar (and the others fixed or at their defaults) has one channel."""
    if not vectorise:
        return None
    cands = [i for i, a in enumerate(grid) if a.name != "mu" and entry.param(a.name).channels]
    if not cands:
        return None
    fn = _evaluator(entry, fixed64, names, rule)
    probe = jax.eval_shape(fn, jax.ShapeDtypeStruct((1,), jnp.float64),
                           jax.ShapeDtypeStruct((1, len(names)), jnp.float64))
    return cands[-1] if probe.shape[-1] == 1 else None


class _Plan:
    """How a grid is computed: texel axes streamed through the quadrature, and at most one
    channel axis computed as the model's channels."""

    def __init__(self, entry, grid: list, fixed64: dict, rule: dict, vectorise: bool):
        names = tuple(a.name for a in grid if a.name != "mu")
        self.grid = grid
        self.chan = _channel_axis(entry, grid, fixed64, names, rule, vectorise)
        self.texel_axes = [a for i, a in enumerate(grid) if i != self.chan]
        self.names = tuple(a.name for a in self.texel_axes if a.name != "mu")
        self.entry, self.fixed64 = entry, fixed64

    def evaluator(self, rule: dict, chan_values=None):
        fixed = dict(self.fixed64)
        if self.chan is not None:
            values = self.grid[self.chan].nodes() if chan_values is None else chan_values
            fixed[self.grid[self.chan].name] = jnp.asarray(values, jnp.float64)
        return _evaluator(self.entry, fixed, self.names, rule)

    def texels(self, index: list | None = None):
        """``mu`` (floored) and parameter rows ``P`` of the texel axes' grid (all nodes, or the
        node indices ``index`` per texel axis)."""
        nodes = [a.nodes() if index is None else a.nodes()[ix]
                 for a, ix in zip(self.texel_axes, index or [None] * len(self.texel_axes),
                                  strict=True)]
        mesh = np.meshgrid(*nodes, indexing="ij")
        flat = {a.name: g.ravel() for a, g in zip(self.texel_axes, mesh, strict=True)}
        n = mesh[0].size
        mu = np.maximum(flat["mu"], MU_FLOOR) if "mu" in flat else None
        P = np.stack([flat[k] for k in self.names], -1) if self.names else np.zeros((n, 0))
        return mu, P, tuple(g for g in mesh[0].shape)

    def arrange(self, E, texel_shape: tuple, chan_axis_pos: int | None = None):
        """Texel-major ``E (K, C)`` -> the grid's axis order with a trailing channel axis."""
        if self.chan is None:
            return E.reshape(texel_shape + (E.shape[-1],))
        out = E.reshape(texel_shape + (E.shape[-1],))
        pos = self.chan if chan_axis_pos is None else chan_axis_pos
        return np.moveaxis(out, -1, pos)[..., None]


def _channels(c: int) -> tuple[str, ...]:
    if c == 1:
        return ("E",)
    if c == 3:
        return ("E_R", "E_G", "E_B")
    return tuple(f"E_{k}" for k in range(c))


def albedo_table(model: str, axes: Mapping[str, AxisSpec], params: Mapping | None = None, *,
                 centres: bool = True, error_estimate: bool = True,
                 progress: Callable[[int, int], None] | None = None,
                 channel_axes: bool = True) -> Table:
    """``E`` of registry entry ``model`` on the grid of ``axes`` (in order; ``"mu"`` must be one
    of them; any other name is a parameter of the entry, over its declared interval unless a
    range is given), the other parameters at ``params`` or the entry's defaults.

    Axes are texel centres by default (``centres=False``: endpoints). The table's channels are
    ``E`` (one channel) or ``E_R, E_G, E_B``. Its metadata holds ``E_avg`` (the average over
    ``mu`` at each node of the other axes, as nested lists, when there are at most 4096) and an
    ``error_estimate``: the largest difference, on a subgrid of up to 8 nodes per axis including
    both ends, against rules with twice the nodes in each direction. ``channel_axes=False``
    computes every axis texel by texel (module docstring: the result is the same).
    ``progress(done, total)`` counts the table's entries and then those of ``E_avg``
    (``N_MU_AVG`` per node of the other axes) when it is computed, in one total."""
    entry = registry_get(model)
    if "mu" not in axes:
        raise ValueError("an albedo table needs a 'mu' axis (e.g. mu=64)")
    fixed = {k: v for k, v in (params or {}).items()}
    for k in fixed:
        entry.param(k)
        if k in axes:
            raise ValueError(f"parameter {k!r} is both an axis and fixed")
    grid = _axes(entry, axes, centres)
    rule = {"n_phi": HALFVECTOR_N_PHI, "generic": (GENERIC_N_MU, GENERIC_N_PHI)}
    fine_rule = {"n_theta": 96, "n_phi": 2 * HALFVECTOR_N_PHI,
                 "generic": (2 * GENERIC_N_MU, 2 * GENERIC_N_PHI)}
    t0 = time.perf_counter()
    with jax.enable_x64(True):
        fixed64 = {k: jnp.asarray(v, jnp.float64) for k, v in fixed.items()}
        plan = _Plan(entry, grid, fixed64, rule, channel_axes)
        fn = plan.evaluator(rule)
        n_chan = grid[plan.chan].n if plan.chan is not None else 1
        mu, P, tshape = plan.texels()
        other = [a for a in grid if a.name != "mu"]
        n_other = int(np.prod([a.n for a in other]))
        with_avg = n_other <= 4096
        # one progress count over the table's entries and then those of E_avg
        n_table = int(np.prod([a.n for a in grid]))
        grand = n_table + (n_other * N_MU_AVG if with_avg else 0)
        E = plan.arrange(_run(fn, mu, P, progress, channels=n_chan, grand_total=grand), tshape)
        seconds = time.perf_counter() - t0
        meta = {
            "kind": "albedo", "model": entry.name, "params": {k: np.asarray(v).tolist()
                                                            for k, v in fixed.items()},
            "layout": {"centres": centres, "image_origin": "top"},
            "quadrature": "verify.albedo.directional_albedo defaults (per lobe), float64",
            "limits": {"mu=0": f"evaluated at mu={MU_FLOOR}"},
            "channel_axis": None if plan.chan is None else grid[plan.chan].name,
            "seconds": round(seconds, 3), "brdf_fit_version": __version__,
        }
        if error_estimate:
            idx = [np.unique(np.linspace(0, a.n - 1, min(a.n, 8)).round().astype(int))
                   for a in grid]
            t_idx = [ix for i, ix in enumerate(idx) if i != plan.chan]
            c_vals = None if plan.chan is None else grid[plan.chan].nodes()[idx[plan.chan]]
            fine = plan.evaluator(fine_rule, c_vals)
            mu2, P2, tshape2 = plan.texels(t_idx)
            E2 = plan.arrange(_run(fine, mu2, P2, None, channels=1 if c_vals is None
                                   else c_vals.size), tshape2)
            E1 = E[np.ix_(*idx)]
            meta["error_estimate"] = {
                "max_abs": float(np.abs(E2 - E1).max()),
                "method": f"against rules with twice the nodes on {E1[..., 0].size} texels "
                          "(up to 8 per axis, ends included)",
            }
        if with_avg:
            avg = _average(plan, fn, progress, offset=n_table, grand_total=grand)
            meta["E_avg"] = {"axes": [a.to_dict() for a in other],
                             "values": avg.tolist()}
    return Table(E, grid, _channels(E.shape[-1]), meta)


def _average(plan: _Plan, fn, progress, offset: int = 0, grand_total: int | None = None):
    """``E_avg`` at every node of the grid's axes other than ``mu`` (in their order, with a
    trailing channel axis), by Gauss-Legendre in ``mu`` (:data:`N_MU_AVG` nodes)."""
    x, w = gauss_legendre_interval(N_MU_AVG, 0.0, 1.0)
    others = [a for a in plan.texel_axes if a.name != "mu"]
    nodes = np.meshgrid(*(a.nodes() for a in others), indexing="ij") if others else []
    P = np.stack([g.ravel() for g in nodes], -1) if others else np.zeros((1, 0))
    M = P.shape[0]
    mu = np.tile(x, M)
    PP = np.repeat(P, x.size, axis=0)
    n_chan = plan.grid[plan.chan].n if plan.chan is not None else 1
    E = _run(fn, mu, PP, progress, channels=n_chan, offset=offset,
             grand_total=grand_total).reshape(M, x.size, -1)
    avg = 2.0 * np.einsum("mkc,k->mc", E, w * x)
    shape = tuple(a.n for a in others)
    if plan.chan is None:
        return avg.reshape(shape + (-1,))
    # position of the channel axis among the grid's axes other than mu
    pos = sum(1 for i, a in enumerate(plan.grid) if i < plan.chan and a.name != "mu")
    return np.moveaxis(avg.reshape(shape + (-1,)), -1, pos)[..., None]


def average_table(model: str, axes: Mapping[str, AxisSpec], params: Mapping | None = None, *,
                  centres: bool = True, progress=None, channel_axes: bool = True) -> Table:
    """``E_avg = 2 Int E(mu) mu dmu`` of registry entry ``model`` on the grid of ``axes`` (the
    entry's parameters; no ``mu`` axis), channels ``E_avg`` (or ``E_avg_R, ...``)."""
    entry = registry_get(model)
    if "mu" in axes:
        raise ValueError("E_avg is averaged over mu: give only parameter axes")
    fixed = dict(params or {})
    for k in fixed:
        entry.param(k)
    grid = _axes(entry, axes, centres)
    rule = {"n_phi": HALFVECTOR_N_PHI, "generic": (GENERIC_N_MU, GENERIC_N_PHI)}
    t0 = time.perf_counter()
    with jax.enable_x64(True):
        fixed64 = {k: jnp.asarray(v, jnp.float64) for k, v in fixed.items()}
        plan = _Plan(entry, grid, fixed64, rule, channel_axes)
        avg = _average(plan, plan.evaluator(rule), progress)
    ch = tuple(c.replace("E", "E_avg", 1) for c in _channels(avg.shape[-1]))
    meta = {"kind": "E_avg", "model": entry.name,
            "params": {k: np.asarray(v).tolist() for k, v in fixed.items()},
            "layout": {"centres": centres, "image_origin": "top"},
            "quadrature": f"Gauss-Legendre in mu, {N_MU_AVG} nodes, of directional_albedo",
            "channel_axis": None if plan.chan is None else grid[plan.chan].name,
            "seconds": round(time.perf_counter() - t0, 3), "brdf_fit_version": __version__}
    return Table(avg, grid, ch, meta)
