"""Lafortune generalised cosine lobes (Lafortune, Foo, Torrance & Greenberg 1997).

E. P. F. Lafortune, S.-C. Foo, K. E. Torrance, D. P. Greenberg, "Non-linear approximation of
reflectance functions", SIGGRAPH 97, pp. 117-126, 1997 (the lobe, eq. 4 as BBM
``include/bsdfmodel/lafortune.h`` reads it; the paper was not available to re-read)::

    f = rho_d/pi + sum_j rho_s,j max(0, Cx_j wi_x wo_x + Cy_j wi_y wo_y + Cz_j wi_z wo_z)^n_j

in the local frame (x = tangent, y = bitangent, z = normal), both directions pointing away from
the surface. Sign convention: the mirror direction of ``wo`` is ``(-wo_x, -wo_y, wo_z)``, so
``-Cx = -Cy = Cz > 0`` is a Phong lobe about the mirror direction (with ``Cz^n = (n+2)/(2 pi)``
exactly the modified-Phong lobe of :class:`~brdf_fit.models.phong.ModifiedPhong`, tested), ``Cx =
Cy > 0`` a retro-reflective lobe, ``|Cx| > Cz`` an off-specular lobe shifted toward grazing, ``Cx
!= Cy`` anisotropic. This is the convention of BBM (its default lobe ``Cxy = -0.577, Cz = 0.577``
is a forward lobe) and of the Ngan 2005 fits; Westin's RSL implementation flips the sign of Cxy
internally "to agree with the description in the SIGGRAPH paper" (models.md 4.21), i.e. it
stores ``-Cxy``: same model, other sign of the stored number. ``rho_s,j`` (default 1) is
redundant with the magnitude of the C's for ``n > 0`` (``rho [C.]^n = [rho^(1/n) C.]^n``); the
paper and the Cornell MDL ``blLfrtn`` data fold it into the C's.

Structure of a lobe. With ``M = diag(Cx, Cy, Cz)``, the lobe is ``rho_s |M wo|^n max(0, s.wi)^n``
with axis ``s = M wo/|M wo|``: a power-cosine lobe about ``s`` scaled by ``|M wo|^n``, which is
what the sampler uses. Reciprocal by construction (``wi^T M wo`` is a symmetric bilinear form).
Energy is conserved only under a constraint on (C, n): the lobe's albedo is
``rho_s |M wo|^n Int_H+ max(0, s.wi)^n cos(theta_i) dwi <= rho_s |M wo|^n 2 pi/(n+1)``
(models.md 4.21); the defaults are measured in :func:`registry_entries`.

Sampling: one-sample mixture (Veach & Guibas 1995) of the cosine warp (probability ~ ``max
rho_d``) and, for each lobe, the power-cosine warp about ``s_j``: ``cos = u0^(1/(n+1))``, density
``(n+1)/(2 pi) max(0, s_j.wi)^n`` (Lafortune & Willems 1994, section 3), chosen with probability
proportional to the lobe's albedo estimate at normal orientation ``max(rho_s,j) |M_j wo|^n_j 2 pi/
(n_j + 2)`` (the estimate of BBM's ``reflectance()``; computed in log space, so ``|M wo|^n`` never
overflows in the weights). The probabilities depend on ``wo`` only; ``pdf`` is the exact mixture
``p_d cos/pi + sum_j p_j (n_j+1)/(2 pi) max(0, s_j.wi)^n_j`` on the upper hemisphere (a share
:data:`PROB_FLOOR` of the probabilities is spread evenly over the reflecting components: a
defensive mixture that bounds the sample weights). The lobe
value is ``|M wo|^n``-scaled, the pdf is the *normalised* power cosine: the two differ by the
factor ``rho_s |M wo|^n 2 pi/(n+1)``, the sample weight of a lone lobe. Power-cosine samples below
the horizon fail (pdf 0, weight 0).

Numerics: powers as ``exp(n log x)`` (finite ``d/dn``; 0 with gradient 0 where the base is at or
below :data:`POW_TINY`); a lobe with ``M wo = 0`` has value 0 everywhere, probability 0 and a
sanitised axis (the normal). The registry entry bounds ``|C| <= 1.1`` and ``n <= 500`` so that
``|C|^n <= 1.1^500 = 5e20`` stays finite in float32, values and gradients.

Quadrature: the lobes are about ``s_j``, not the mirror direction, and declare no
``quadrature_lobe()``; :func:`brdf_fit.verify.albedo.directional_albedo` integrates them with the
generic 64 x 128 Gauss-Legendre x trapezoid rule. Measured against a brute-force 1024 x 2048
rule (tests/test_lafortune.py): relative error ~1e-14 for the default entry (n = 12 and 4) and
for normalised Phong-like lobes up to n = 300, 3e-9 at n = 500 (the entry's bound), but
3e-4..9e-3 at n = 2000 and 35-50% at n = 1e4: lobes sharper than the entry allows need a
lobe-adapted rule.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from brdf_fit.core.frame import join, split
from brdf_fit.core.numerics import INV_PI, INV_TWO_PI, NORM_EPS, safe_log, safe_normalize3
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import ParameterError, check_param, check_scalar
from brdf_fit.core.warp import sample_cosine_hemisphere
from brdf_fit.models._base import AbstractBRDF, expand_channels
from brdf_fit.models._lobes import (
    finish_sample,
    sample_power_cosine_about,
    sanitize_direction,
    sanitize_wo,
    upper,
)

__all__ = ["CosineLobe", "Lafortune", "registry_entries"]

LOG_TWO_PI = math.log(2.0 * math.pi)

_LFTG_1997 = (
    "E. P. F. Lafortune, S.-C. Foo, K. E. Torrance, D. P. Greenberg, Non-linear approximation of "
    "reflectance functions, SIGGRAPH 97, pp. 117-126, 1997"
)


#: Bases of the lobe powers at or below this count as 0 (value and gradient 0): ``d/dx x^n =
#: n x^n / x`` then never meets ``1/x = inf`` (a denormal base in float32 gave ``0 * inf = NaN``
#: at n = 0); 1e-30 keeps ``1/x <= 1e30``, and moves the edge of an n = 0 lobe by 1e-30 only.
POW_TINY = 1e-30


#: Defensive mixture (T. Hesterberg, "Weighted average importance sampling and defensive mixture
#: distributions", Technometrics 37(2), 1995): a fraction 1e-3 of the lobe-choice probability is
#: shared equally by the components that reflect. A lobe of |C|^n ~ 1e20 otherwise leaves the
#: diffuse term a probability ~1e-21, its samples weights ~1e21 and, in float32, infinite
#: gradients of f cos/pdf; with the floor every weight is within 1e3 K of its component's own.
PROB_FLOOR = 1e-3


def _pow(x, n):
    """``max(0, x)^n`` as ``exp(n log x)`` for ``x > POW_TINY``, 0 elsewhere (double where)."""
    ok = x > POW_TINY
    return jnp.where(ok, jnp.exp(n * jnp.log(jnp.where(ok, x, 1.0))), 0.0)


def _cmax(x):
    """Maximum over channels; Python numbers stay weakly typed (no float64 leaks into float32)."""
    return x if isinstance(x, int | float) else jnp.max(jnp.asarray(x))


#: Coefficient bound of the registry entry: |C| <= 1.1 covers every energy-normalised Phong-like
#: lobe (``Cz = ((n+2)/(2 pi))^(1/n)`` peaks at 1.068 near n = 15) and the published light-blue
#: house-paint fit (|C| <= 1.032, models.md 4.21); with n <= N_MAX, |C|^n <= 1.1^500 = 5e20.
C_MAX = 1.1
N_MAX = 500.0


class CosineLobe(eqx.Module):
    """One generalised cosine lobe ``rho_s max(0, Cx wi_x wo_x + Cy wi_y wo_y + Cz wi_z wo_z)^n``
    (a part of :class:`Lafortune`, not a BRDF on its own). ``cx, cy, cz`` (signed) and the
    exponent are scalars (they fix the lobe's geometry, which the sampler needs); ``rho_s`` may
    carry channels."""

    cx: Scalar = bounded(-1.0, lo=-C_MAX, hi=C_MAX)
    cy: Scalar = bounded(-1.0, lo=-C_MAX, hi=C_MAX)
    cz: Scalar = bounded(1.0, lo=-C_MAX, hi=C_MAX)
    exponent: Scalar = bounded(10.0, lo=0.0, hi=N_MAX)
    rho_s: Channels = bounded(1.0, lo=0.0, channels=True)

    def __check_init__(self):
        owner = "CosineLobe"
        for name in ("cx", "cy", "cz"):
            check_param(name, getattr(self, name), owner=owner)
            check_scalar(name, getattr(self, name), owner)
        check_param("exponent", self.exponent, lo=0.0, owner=owner)
        check_scalar("exponent", self.exponent, owner)
        check_param("rho_s", self.rho_s, lo=0.0, owner=owner)

    def value(self, ix, iy, iz, ox, oy, oz):
        """``max(0, wi^T M wo)^n`` (without ``rho_s``)."""
        b = self.cx * ix * ox + self.cy * iy * oy + self.cz * iz * oz
        return _pow(b, self.exponent)

    def axis(self, ox, oy, oz):
        """``(sx, sy, sz, log|M wo|, ok)``: the lobe axis ``M wo/|M wo|`` (the normal where
        ``M wo`` vanishes, ``ok`` False there) and the log of its length."""
        mx, my, mz = self.cx * ox, self.cy * oy, self.cz * oz
        l2 = mx * mx + my * my + mz * mz
        sx, sy, sz, ok = safe_normalize3(mx, my, mz)
        sz = jnp.where(ok, sz, 1.0)
        return sx, sy, sz, 0.5 * safe_log(l2, NORM_EPS), ok


class Lafortune(AbstractBRDF):
    """Lafortune et al. 1997 generalised cosine lobes with a Lambertian term (module docstring)::

        f = rho_d/pi + sum_j rho_s,j max(0, Cx_j wi_x wo_x + Cy_j wi_y wo_y + Cz_j wi_z wo_z)^n_j

    ``lobes`` is a tuple of any number of :class:`CosineLobe` (zero lobes: Lambert).
    ``rho_d`` in [0, 1] may carry channels. Sampler: cosine + one power-cosine warp per lobe about
    its axis ``normalize(M_j wo)``, exact mixture pdf (module docstring).
    """

    #: the checks look at three view azimuths (brdf_fit.checks._views)
    anisotropic: ClassVar[bool] = True

    rho_d: Channels = bounded(0.3, lo=0.0, hi=1.0, channels=True)
    lobes: tuple[CosineLobe, ...] = (CosineLobe(),)

    def __check_init__(self):
        check_param("rho_d", self.rho_d, lo=0.0, hi=1.0, owner="Lafortune")
        if not isinstance(self.lobes, tuple) or not all(
                isinstance(lobe, CosineLobe) for lobe in self.lobes):
            raise ParameterError("Lafortune: lobes must be a tuple of CosineLobe")

    # ------------------------------------------------------------------ pieces

    def _probabilities(self, ox, oy, oz):
        """``(p_d, [p_j], [axis_j])`` at the (sanitised) view direction: lobe choice proportional
        to ``max rho_d`` and to ``max(rho_s,j) |M_j wo|^n_j 2 pi/(n_j + 2)`` (in log space)."""
        axes, logs, valid = [], [], []
        hd = jnp.asarray(_cmax(self.rho_d))
        vd = hd > 0
        logs.append(jnp.where(vd, safe_log(hd), 0.0) * jnp.ones_like(oz))
        valid.append(vd & jnp.ones_like(oz, dtype=bool))
        for lobe in self.lobes:
            sx, sy, sz, log_len, ok = lobe.axis(ox, oy, oz)
            axes.append((sx, sy, sz, ok))
            hs = jnp.asarray(_cmax(lobe.rho_s))
            n = lobe.exponent
            lw = safe_log(hs) + n * log_len + LOG_TWO_PI - jnp.log(n + 2.0)
            v = ok & (hs > 0)
            logs.append(jnp.where(v, lw, 0.0))
            valid.append(v)
        L = jnp.stack(jnp.broadcast_arrays(*logs), axis=0)
        V = jnp.stack(jnp.broadcast_arrays(*valid), axis=0)
        m = jnp.max(jnp.where(V, L, -jnp.inf), axis=0)
        any_valid = jnp.any(V, axis=0)
        ms = jnp.where(any_valid, m, 0.0)
        w = jnp.where(V, jnp.exp(jnp.where(V, L - ms, 0.0)), 0.0)
        tot = jnp.sum(w, axis=0)
        share = jnp.where(V, 1.0, 0.0).astype(w.dtype)
        share = share / jnp.maximum(jnp.sum(share, axis=0), 1.0)
        p = (1.0 - PROB_FLOOR) * w / jnp.where(any_valid, tot, 1.0) + PROB_FLOOR * share
        p_d = jnp.where(any_valid, p[0], 1.0)
        return p_d, [p[j + 1] for j in range(len(self.lobes))], axes

    # ------------------------------------------------------------------ interface

    def eval(self, wi, wo):
        ok = upper(wi, wo)
        ix, iy, iz = split(wi)
        ox, oy, oz = split(wo)
        ch = self.channels()
        val = self.rho_d * INV_PI
        for lobe in self.lobes:
            v = lobe.value(ix, iy, iz, ox, oy, oz)
            val = val + lobe.rho_s * expand_channels(v, ch)
        return jnp.where(expand_channels(ok, ch), val, 0.0)

    def pdf(self, wi, wo):
        ok = upper(wi, wo)
        ox, oy, oz = split(sanitize_direction(wo, wo[..., 2] > 0))
        ix, iy, iz = split(wi)
        p_d, p_lobes, axes = self._probabilities(ox, oy, oz)
        val = p_d * jnp.maximum(iz, 0.0) * INV_PI
        for lobe, pj, (sx, sy, sz, _) in zip(self.lobes, p_lobes, axes, strict=True):
            c = jnp.maximum(sx * ix + sy * iy + sz * iz, 0.0)
            n = lobe.exponent
            val = val + pj * (n + 1.0) * INV_TWO_PI * _pow(c, n)
        return jnp.where(ok, val, 0.0)

    def sample(self, wo, uc, u):
        wos, okv = sanitize_wo(wo)
        p_d, p_lobes, axes = self._probabilities(*split(wos))
        wi = sample_cosine_hemisphere(u)
        cdf = p_d
        for lobe, pj, (sx, sy, sz, _) in zip(self.lobes, p_lobes, axes, strict=True):
            ws = sample_power_cosine_about(join(sx, sy, sz), u, lobe.exponent)
            pick = (uc >= cdf) & (uc < cdf + pj)
            wi = jnp.where(pick[..., None], ws, wi)
            cdf = cdf + pj
        return finish_sample(self, wi, wo, okv)

    def selection_hint(self):
        """``max rho_d + sum_j max(rho_s,j) max(|C_j|)^n_j 2 pi/(n_j + 2)`` (an upper estimate of
        the albedo at normal orientation; the power is capped at e^80 against overflow)."""
        h = _cmax(self.rho_d)
        for lobe in self.lobes:
            cmax = jnp.maximum(jnp.maximum(jnp.abs(lobe.cx), jnp.abs(lobe.cy)), jnp.abs(lobe.cz))
            p = jnp.exp(jnp.minimum(lobe.exponent * safe_log(cmax), 80.0))
            h = h + _cmax(lobe.rho_s) * p * (2.0 * math.pi) / (lobe.exponent + 2.0)
        return h


# ----------------------------------------------------------------------------- registry entry


def registry_entries():
    """:class:`brdf_fit.registry.Entry` for the two-lobe Lafortune model (not registered here)."""
    def coef(name, default, doc):
        return Param(name, default, lo=-C_MAX, hi=C_MAX, doc=doc)

    def expo(name, default, doc):
        return Param(name, default, lo=0.0, hi=N_MAX, doc=doc)

    def build(rho_d, cx_1, cy_1, cz_1, n_1, cx_2, cy_2, cz_2, n_2):
        return Lafortune(rho_d=rho_d, lobes=(
            CosineLobe(cx=cx_1, cy=cy_1, cz=cz_1, exponent=n_1),
            CosineLobe(cx=cx_2, cy=cy_2, cz=cz_2, exponent=n_2),
        ))

    return [
        Entry(
            name="lafortune",
            builder=build,
            params=(
                Param("rho_d", (0.3, 0.25, 0.2), lo=0.0, hi=1.0, channels=True,
                      doc="diffuse albedo (f_d = rho_d/pi)"),
                coef("cx_1", -1.0, "lobe 1 coefficient along the tangent x (< 0: forward)"),
                coef("cy_1", -0.9, "lobe 1 coefficient along the bitangent y"),
                coef("cz_1", 0.95, "lobe 1 coefficient along the normal"),
                expo("n_1", 12.0, "lobe 1 exponent"),
                coef("cx_2", 0.5, "lobe 2 coefficient along x (> 0: retro-reflective)"),
                coef("cy_2", 0.4, "lobe 2 coefficient along y"),
                coef("cz_2", 0.6, "lobe 2 coefficient along the normal"),
                expo("n_2", 4.0, "lobe 2 exponent"),
            ),
            reference=f"{_LFTG_1997}; sign convention of BBM include/bsdfmodel/lafortune.h",
            description=(
                "rho_d/pi + sum of 2 generalised cosine lobes max(0, Cx lx vx + Cy ly vy + "
                "Cz lz vz)^n (forward anisotropic lobe + retro-reflective lobe by default); "
                "reciprocal; energy conserving only under a constraint on (C, n)"
            ),
            aliases=("lafortune-1997", "generalised-cosine"),
            tags=("anisotropic",),
            year=1997,
            catalogue="Lafortune",
            sampler="cosine + power-cosine about each lobe axis, exact mixture pdf",
        ),
    ]
