"""Westin, Arvo & Torrance (1992): the BRDF of an explicit micro-geometry, computed by Monte Carlo
ray tracing (a virtual gonioreflectometer) and evaluated from a precomputed table.

S. H. Westin, J. R. Arvo, K. E. Torrance, "Predicting reflectance functions from complex
surfaces", SIGGRAPH 92, Computer Graphics 26(2):255-264, 1992: trace rays at a piece of
micro-geometry whose primitives carry a finer-scale BRDF, collect the escaping rays, project them
onto a smooth representation that can be evaluated everywhere, reciprocal by symmetrisation.
The tables are computed by :mod:`brdf_fit.tables.westin` (layer 3; its docstring states the
geometry, the tracer, the basis and every approximation) and shipped as
``brdf_fit/resources/tables/westin_<preset>.npz`` (+ ``.json``), read here with
:func:`brdf_fit.core.table.load_packaged_table`.

The BRDF::

    f(wi, wo) = scale * F(theta_i, theta_o, phi_d)

``F`` is the table (1/sr): cosine-weighted averages of the simulated BRDF over bin pairs, at the
bins' centres, interpolated multilinearly (:meth:`brdf_fit.core.table.Table.lookup`, clamped to
the edge cells beyond the outermost centres); ``theta = atan2(|w_xy|, w_z)``; ``phi_d`` in
``[0, pi]`` the angle between the horizontal projections of ``wi`` and ``wo`` (0: back-scatter),
0 when either projection vanishes. At a pole ``phi_d`` is undefined and the true ``f`` does not
depend on it, but the first bin's cells (centred 2.8 degrees off the pole) carry their Monte
Carlo noise in ``phi_d``: so below the first centre, ``min(theta_i, theta_o) < c_0``, ``F`` is
blended linearly (weight ``min(theta_i, theta_o) / c_0``) into its mean over ``phi_d``, which
makes ``f`` continuous at the poles. Both tables are symmetric in ``(theta_i, theta_o)`` and the
blend weight is too, so ``f`` is **reciprocal by construction** (to rounding), and non-negative
(ray weights are).
``scale`` (channels, the fittable parameter) is a linear tint of the grey simulation: it is not
the colour of the fibres (multiple bounces make that non-linear), but it keeps the model linear
in its parameter, as ``select`` and ``fit`` like it. The table's channel ``se`` is the Monte Carlo
standard error of every cell (:meth:`Westin.mc_error`; the summary is in the metadata,
:meth:`Westin.table_meta`).

**Sampling**: the fallback of :mod:`brdf_fit.models._fallback` (cosine + Beckmann half-vector
mixture, exact pdf) with the preset's width :data:`SAMPLER_ALPHA` and cosine probability
:data:`P_COSINE`: the velvet lobe is broad (fibre sides, floor) with a forward peak at grazing.

**Measured** (tests/models/test_westin.py; the simulation's own accuracy is in
:mod:`brdf_fit.tables.westin`): all ten ``run_checks`` pass for ``westin-velvet`` (three not
applicable: no microfacet lobe); reciprocity 1.2e-15; directional albedo 0.282 (normal) to 0.470
(grazing) with ``scale = 1``, equal to the tracer's own albedo to 0.21%; continuous at the poles;
gradients equal central differences to 1e-5. Evaluation (jitted, float64, 65 536 pairs, 2-core
CPU): 130 ns per pair, 32x Lambert in the same run (``benchmarks/bench_catalogue_cost.py
--entries westin-velvet``: three ``atan2``, a trilinear and a bilinear lookup). Precomputation:
327 s once per preset (16.8 million traced paths).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.numerics import safe_hypot
from brdf_fit.core.params import Channels, Entry, Param, bounded
from brdf_fit.core.table import Table, load_packaged_table
from brdf_fit.core.validate import ParameterError, check_param
from brdf_fit.models._base import AbstractBRDF, expand_channels
from brdf_fit.models._fallback import cosine_beckmann_pdf, cosine_beckmann_sample
from brdf_fit.models._lobes import max_over_channels, sanitize_pair

__all__ = ["P_COSINE", "PRESET_NAMES", "SAMPLER_ALPHA", "Westin", "registry_entries",
           "table_file"]

#: the shipped presets (``brdf_fit.tables.westin.PRESETS``)
PRESET_NAMES = ("velvet",)
#: probability of the cosine lobe in the fallback sampler (the simulated lobe is mostly broad)
P_COSINE = 0.5
#: Beckmann width of the fallback sampler's half-vector lobe (the forward peak of the fibres'
#: GGX alpha = 0.3, broadened by their curvature)
SAMPLER_ALPHA = 0.5

_WESTIN_1992 = ('S. H. Westin, J. R. Arvo, K. E. Torrance, "Predicting reflectance functions '
                'from complex surfaces", SIGGRAPH 92, Computer Graphics 26(2):255-264, 1992')


def table_file(preset: str) -> str:
    return f"westin_{preset}.npz"


@functools.cache
def _table64(preset: str) -> Table:
    if preset not in PRESET_NAMES:
        raise ParameterError(f"Westin: unknown preset {preset!r}; presets: "
                             f"{', '.join(PRESET_NAMES)}")
    return load_packaged_table(table_file(preset))


@functools.cache
def _table(preset: str, dtype_name: str) -> tuple[Table, Table]:
    """The ``f`` channel alone, in the evaluation dtype (one gather per corner, not two), and its
    mean over ``phi_d`` (a 2-D table in ``(theta_i, theta_o)``, for the poles)."""
    t = _table64(preset)
    f = np.asarray(t.channel("f"), np.float64)
    dt = np.dtype(dtype_name)
    return (Table(f.astype(dt)[..., None], t.axes, ("f",), {}),
            Table(f.mean(axis=-1).astype(dt)[..., None], t.axes[:2], ("f",), {}))


def angles(wi, wo):
    """``(theta_i, theta_o, phi_d)`` of two directions (sanitised: both above the horizon
    assumed), with finite gradients everywhere: ``theta = atan2(hypot(x, y), z)`` (the
    guarded hypot has gradient 0 at the pole) and ``phi_d = atan2(|c|, d)``, ``c``, ``d`` the
    cross and dot products of the horizontal projections, 0 where both vanish (a direction at
    the pole: ``f`` does not depend on ``phi_d`` there)."""
    ix, iy, iz = wi
    ox, oy, oz = wo
    th_i = jnp.arctan2(safe_hypot(ix, iy), iz)
    th_o = jnp.arctan2(safe_hypot(ox, oy), oz)
    c = ix * oy - iy * ox
    d = ix * ox + iy * oy
    ok = (c != 0) | (d != 0)
    ph = jnp.where(ok, jnp.arctan2(jnp.abs(c), jnp.where(ok, d, 1.0)), 0.0)
    return th_i, th_o, ph


class Westin(AbstractBRDF):
    """The simulated BRDF of a micro-geometry from a precomputed table (module docstring).
    ``preset``: ``"velvet"`` (static); ``scale``: a linear tint (channels)."""

    scale: Channels = bounded(1.0, lo=0.0, hi=1.0, channels=True)
    preset: str = eqx.field(static=True, default="velvet")

    def __check_init__(self):
        check_param("scale", self.scale, lo=0.0, owner="Westin")
        _table64(self.preset)  # unknown preset: ParameterError now, not at the first eval

    def table(self) -> Table:
        """The shipped table (float64): channels ``f`` (1/sr) and ``se`` (its Monte Carlo
        standard error), axes ``theta_i``, ``theta_o``, ``phi_d``."""
        return _table64(self.preset)

    def table_meta(self) -> dict:
        """The table's metadata: geometry, rays, seed, seconds, Monte Carlo error summary,
        albedo per incident bin with its error, truncated weight."""
        return _table64(self.preset).meta

    def mc_error(self, wi, wo):
        """The Monte Carlo standard error of ``f`` at ``(wi, wo)`` (the table's ``se`` channel,
        interpolated like ``f``, times ``scale``)."""
        t = _table64(self.preset)
        valid, wi_s, wo_s = sanitize_pair(wi, wo)
        se = t.lookup(*angles(wi_s, wo_s))[..., 1]
        ch = self.channels()
        return jnp.where(expand_channels(valid, ch), self.scale * expand_channels(se, ch), 0.0)

    def table_value(self, wi, wo):
        """``F(theta_i, theta_o, phi_d)`` (1/sr), 0 below the horizon; near the poles blended
        into its mean over ``phi_d`` (module docstring)."""
        valid, wi_s, wo_s = sanitize_pair(wi, wo)
        dt = jnp.result_type(wi, wo)
        t, t_mean = _table(self.preset, str(np.dtype(dt)))
        th_i, th_o, ph = angles(wi_s, wo_s)
        F = t.lookup(th_i, th_o, ph)[..., 0]
        F0 = t_mean.lookup(th_i, th_o)[..., 0]
        c0 = 0.5 * t.axes[0].spacing()  # the first bin's centre
        w = jnp.minimum(jnp.minimum(th_i, th_o) / c0, 1.0)
        return jnp.where(valid, F0 + w * (F - F0), 0.0)

    def eval(self, wi, wo):
        valid = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        ch = self.channels()
        F = self.table_value(wi, wo)
        return jnp.where(expand_channels(valid, ch), self.scale * expand_channels(F, ch), 0.0)

    def pdf(self, wi, wo):
        return cosine_beckmann_pdf(wi, wo, SAMPLER_ALPHA, P_COSINE)

    def sample(self, wo, uc, u):
        return cosine_beckmann_sample(self, wo, uc, u, SAMPLER_ALPHA, P_COSINE)

    def selection_hint(self):
        return max_over_channels(self.scale)


# ----------------------------------------------------------------------------- registry

_WESTIN_FAILURES: dict[str, str] = {}


def _entry(name: str, preset: str, description: str, tags=()) -> Entry:
    return Entry(
        name=name,
        builder=lambda scale: Westin(scale=scale, preset=preset),
        params=(Param("scale", (1.0, 1.0, 1.0), lo=0.0, hi=1.0, channels=True,
                      doc="linear tint of the simulated (grey) BRDF"),),
        reference=_WESTIN_1992,
        description=description,
        expected_failures=dict(_WESTIN_FAILURES),
        tags=tuple(tags),
        year=1992,
        catalogue="Westin",
        sampler="cosine + Beckmann half-vector mixture (exact pdf)",
    )


def registry_entries():
    """``westin-velvet``: the preset is fixed per entry (it selects a table), ``scale`` is the
    fittable parameter."""
    return [
        _entry("westin-velvet", "velvet",
               "Westin 1992: Monte Carlo ray tracing of a velvet pile (random upright fibres, "
               "GGX-plastic, 20 radii long, half the top covered, over a Lambert floor; "
               "multiple bounces), tabulated over (theta_i, theta_o, phi_d), symmetrised; "
               "MC error 1.5% per cell (median, max 4.7%); precomputed once in 327 s "
               "(16.8M paths), eval ~130 ns"),
    ]
