"""Granier-Heidrich layered RGB BRDF (X. Granier, W. Heidrich, "A simple layered RGB BRDF model",
Pacific Graphics 2002, pp. 30-37; Graphical Models 65(4):171-184, 2003; models.md 4.25), as
implemented by Peter Stuart's RenderMan shader ``granier.sl`` (2002, "Thin film interference BRDF
as described in 'A Simple layered RGB BRDF model' by Granier and Heidrich"; read in its shrimp
version ``LocIllumGranier``, luisbarrancos/shrimp ``rsl_shrimp_shadingmodels.h``).

Which source, and why
---------------------

The paper's text beyond its abstract and introduction was not available to us (only its front
page is in the public corpora searched), so no equation number of the paper is cited and
models.md 4.25 stays UNVERIFIED against it. Every term below is pinned to the one public
implementation whose author states that it follows the paper (the shader above), and is written
exactly as that shader computes it, with the assumptions listed further down. A second public
page (bhsunshine.com/shaders/interfere.html) documents the same shader's parameters only.

The model (per channel ``c`` with index ``eta_c`` and wavelength ``lambda_c``; local frame
``n = z``, ``cl = n.wi``, ``cv = n.wo``)
------------------------------------------------------------------------------------------

A thin transparent layer of index ``eta_c`` (relative to the outside) and thickness ``d`` (nm) lies
on a base surface of normal ``N1``. Specular part (the shader's ``specf``)::

    Kr = F(cl, eta_c),  Kt = 1 - Kr,  Kto = 1 - F(cv, eta_c)     RSL fresnel(): F the exact
                                                                  unpolarised dielectric Fresnel
    r  = 2 cl n - wi                      mirror of wi about n:  r.wo = 2 cl cv - wi.wo
    mu_l = sqrt(1 - (1 - cl^2)/eta_c^2),  mu_v alike               refracted cosines (Snell)
    c1 = mu_l mu_v - (wi.wo - cl cv)/eta_c^2                       = rti . (-to), below
    S_c = Kr max(0, r.wo)^e0 + Kt Kto max(0, c1)^e1

where ``ti``/``to`` are ``wi``/``wo`` refracted into the layer, ``rti = reflect(ti, N1)`` the
refracted light mirrored by the base, and ``-to`` the refracted view direction turned upward;
with ``N1 = n`` their dot product is ``c1`` above (unit vectors, so ``c1 <= 1``, equality at the
mirror configuration). Diffuse part (the shader's ``difff/2``), with ``T_d`` the paper's average
transmission as the shader writes it::

    T_d = (80/21) eta_c/(eta_c + 1)^2
    D_c = (1 + 2 cos(4 pi eta_c d/lambda_c) sqrt(T_d (1 - T_d)))/2

The shader returns ``Cl (Kd Cs D + Ks S) max(0, n.L)``; the BRDF is therefore

    f_c = (kd_c D_c + ks_c S_c)/pi          kd_c = Kd Cs_c (one colour parameter here)

Assumptions (each one a choice the shader does not make for us)
----------------------------------------------------------------

* ``1/pi``: RenderMan's ``Cl`` is scaled so that ``Kd diffuse()`` of a white matte surface has
  reflectance ``Kd``; the whole shader expression is divided by ``pi`` (one uniform scale, so the
  shader's relative weights are kept). Then ``D_c <= 1`` (``sqrt(T_d(1 - T_d)) <= 1/2``) and the
  diffuse albedo is at most ``kd``.
* ``N1 = n``: the shader perturbs the base normal ``N1`` with noise (a texture-space variation,
  outside a BRDF); here the base is parallel to the top interface. Then the shader's
  total-internal-reflection test ``ti.N1 >= 0 or to.N1 >= 0 or rti.to >= 0 -> Kt = 0`` reduces
  to ``c1 <= 0``, where ``max(0, c1)^e1`` is 0 anyway: entering a denser layer (``eta >= 1``,
  the registry interval) never totally reflects.
* ``Kt = 1 - Kr``: the RenderMan Interface's ``fresnel()`` returns the energy transmittance; no
  radiance (``eta^2``) factor is applied, as in the shader.
* ``max(0, .)`` on ``r.wo``: the shader calls ``pow(ri.V, e0)`` without a clamp, undefined in RSL
  for a negative base and a non-integer exponent; we take 0 there (the Phong convention).
* No absorption in the layer and no interference phase in the specular part: the shader has
  neither (the interference is carried by the diffuse ``cos(4 pi eta d/lambda)`` only, whose
  phase does not depend on the directions). models.md 4.25's outline ("phase term
  ``cos(4 pi eta d cos(theta_t)/lambda)`` in the specular") is not what the public code does; we
  follow the code, which is the only pinned source.
* ``lambda = (645, 525, 445)`` nm, the shader's documented RGB wavelengths (``wavelengths_nm``,
  static; its length fixes the channel count).

Properties: not reciprocal (``Kr`` depends on ``wi`` only); the ``Kt Kto`` lobe and the diffuse
term are reciprocal. The Phong lobes are unnormalised (their albedo falls like ``1/e``), so
energy is conserved at typical parameters; the first lobe has ``Kr <= 1`` at grazing light, so at
small ``e0`` and ``ks = 1`` the albedo can exceed the diffuse bound.

Identifiability: ``d`` enters only through the per-channel constant ``kd_c D_c(eta_c, d)`` (the
shader's interference does not depend on the directions), and ``eta_c`` is fixed by the specular
part, so ``d`` and ``kd`` cannot be fitted together (3 constants, 4 unknowns): hold ``d`` (or one
``kd`` channel) fixed when fitting. With ``d`` held, noise-free recovery of the other parameters
reaches ~1e-13 relative.

Sampler: cosine-weighted hemisphere (``pdf = n.wi/pi``, exact); ``weight = pi f``, bounded by
``kd + 2 ks``.

Quadrature: ``quadrature_lobe()`` returns ``("mirror", min(e0, e1))``: both lobes peak at the
mirror direction of ``wo``; the ``e1`` lobe in refracted angles is wider outside, and the graded
mirror rule resolves the wider of the two (tests/test_granier_heidrich.py compares it with a fine
generic rule).

Numerics: invalid lanes (either direction at or below the horizon) see the normal before any
formula (double where) and are masked afterwards. ``mu`` is ``sqrt(((eta - 1)(eta + 1) + c^2)/
eta^2) >= c > 0`` on valid lanes (no cancellation near ``eta = 1``); the powers use
:func:`~brdf_fit._numerics.safe_pow` (finite gradient in the exponent at a zero base); ``T_d < 1``
for ``eta >= 1`` (its maximum 80/84 is at ``eta = 1``), so ``sqrt(T_d (1 - T_d))`` needs no guard.
No epsilon is introduced.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp

from brdf_fit.core.fresnel import dielectric
from brdf_fit.core.numerics import INV_PI, safe_pow, safe_sqrt
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import ParameterError, check_param, check_scalar, concrete
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe
from brdf_fit.models._lobes import cosine_pdf, max_over_channels, sample_cosine, sanitize_pair

__all__ = ["GranierHeidrich", "WAVELENGTHS_NM", "registry_entries"]

#: The shader's RGB wavelengths in nm ("use [645 525 445]").
WAVELENGTHS_NM = (645.0, 525.0, 445.0)
#: The shader's average transmission constant ``T_d = (80/21) eta/(eta + 1)^2``.
TD_FACTOR = 80.0 / 21.0

_GH_2003 = (
    "X. Granier, W. Heidrich, A simple layered RGB BRDF model, Pacific Graphics 2002, pp. 30-37; "
    "Graphical Models 65(4):171-184, 2003"
)
_STUART_2002 = (
    "P. Stuart, granier.sl (RenderMan shader, 2002; shrimp rsl_shrimp_shadingmodels.h "
    "LocIllumGranier)"
)


def _channels_ok(name, value, n, owner):
    v = concrete(value)
    if v is not None and v.dtype != object and v.ndim > 0 and v.shape[-1] not in (1, n):
        raise ParameterError(
            f"{owner}: parameter {name!r} has {v.shape[-1]} channels, the model has {n} "
            f"wavelengths")


def diffuse_factor(eta, d, wavelengths_nm=WAVELENGTHS_NM):
    """``D_c = (1 + 2 cos(4 pi eta_c d/lambda_c) sqrt(T_d (1 - T_d)))/2`` per channel, shape
    ``(C,)``, with ``T_d = (80/21) eta/(eta + 1)^2`` (the shader's diffuse term)."""
    eta = jnp.asarray(eta)
    rows = []
    for k, lam in enumerate(wavelengths_nm):
        if eta.ndim == 0:
            e = eta
        else:
            e = eta[..., k] if eta.shape[-1] > 1 else eta[..., 0]
        td = TD_FACTOR * e / ((e + 1.0) * (e + 1.0))
        rows.append(0.5 * (1.0 + 2.0 * jnp.cos((4.0 * math.pi / lam) * e * d)
                           * jnp.sqrt(td * (1.0 - td))))
    return jnp.stack(rows, axis=-1)


class GranierHeidrich(AbstractBRDF):
    """Granier & Heidrich's layered RGB BRDF as P. Stuart's ``granier.sl`` computes it (see the
    module docstring for the formula, the source and the assumptions).

    ``kd``, ``ks`` and ``eta`` may carry channels (1 or ``len(wavelengths_nm)``); ``d`` (layer
    thickness, nm), ``e0`` (top-surface lobe exponent) and ``e1`` (base lobe exponent, in the
    refracted directions) are scalars. Outputs always carry ``len(wavelengths_nm)`` channels.
    """

    kd: Channels = bounded(0.7, lo=0.0, hi=1.0, channels=True)
    ks: Channels = bounded(1.0, lo=0.0, hi=1.0, channels=True)
    eta: Channels = bounded((1.4, 1.45, 1.6), lo=1.0, hi=3.0, channels=True)
    d: Scalar = bounded(70.0, lo=0.0, hi=1000.0)
    e0: Scalar = bounded(90.0, lo=0.0, hi=1e4)
    e1: Scalar = bounded(170.0, lo=0.0, hi=1e4)
    wavelengths_nm: tuple[float, ...] = eqx.field(static=True, default=WAVELENGTHS_NM)

    def __check_init__(self):
        owner = "GranierHeidrich"
        n = len(self.wavelengths_nm)
        check_param("kd", self.kd, lo=0.0, owner=owner)
        check_param("ks", self.ks, lo=0.0, owner=owner)
        check_param("eta", self.eta, lo=1.0, owner=owner)
        check_param("d", self.d, lo=0.0, owner=owner)
        check_param("e0", self.e0, lo=0.0, owner=owner)
        check_param("e1", self.e1, lo=0.0, owner=owner)
        for name in ("d", "e0", "e1"):
            check_scalar(name, getattr(self, name), owner)
        for name in ("kd", "ks", "eta"):
            _channels_ok(name, getattr(self, name), n, owner)
        if n < 1 or any(not (lam > 0) for lam in self.wavelengths_nm):
            raise ParameterError(f"{owner}: parameter 'wavelengths_nm' must be positive, got "
                                 f"{self.wavelengths_nm}")

    def channels(self) -> int:
        return len(self.wavelengths_nm)

    def _specular(self, wi, wo):
        """Validity mask and ``S_c`` of shape ``batch + (C,)`` (sanitised lanes)."""
        ok, (ixs, iys, izs), (oxs, oys, ozs) = sanitize_pair(wi, wo)
        cl, cv = izs[..., None], ozs[..., None]
        tan_dot = (ixs * oxs + iys * oys)[..., None]  # wi.wo - cl cv
        eta = jnp.asarray(self.eta)
        inv_e2 = 1.0 / (eta * eta)
        em1 = (eta - 1.0) * (eta + 1.0)
        mu_l = safe_sqrt((em1 + cl * cl) * inv_e2)
        mu_v = safe_sqrt((em1 + cv * cv) * inv_e2)
        c1 = mu_l * mu_v - tan_dot * inv_e2
        r_dot_v = cl * cv - tan_dot  # 2 cl cv - wi.wo
        kr = dielectric(cl, eta)
        kt = 1.0 - kr
        kto = 1.0 - dielectric(cv, eta)
        spec = kr * safe_pow(r_dot_v, self.e0) + kt * kto * safe_pow(c1, self.e1)
        return ok, spec

    def eval(self, wi, wo):
        ok, spec = self._specular(wi, wo)
        diff = diffuse_factor(self.eta, self.d, self.wavelengths_nm)
        val = (self.kd * diff + self.ks * spec) * INV_PI
        return jnp.where(ok[..., None], val, 0.0)

    def pdf(self, wi, wo):
        return cosine_pdf(wi, wo)

    def sample(self, wo, uc, u):
        return sample_cosine(self, wo, u)

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): power-cosine lobes about the
        mirror direction; the wider one (smaller exponent) sets the grading."""
        return QuadratureLobe("mirror", jnp.minimum(jnp.asarray(self.e0), jnp.asarray(self.e1)))

    def selection_hint(self):
        return max_over_channels(self.kd) + max_over_channels(self.ks)


# ----------------------------------------------------------------------------- registry entries

_GH_FAILURES: dict[str, str] = {
    "reciprocity": (
        "the top-surface lobe is weighted by the Fresnel reflectance of the light direction only "
        "(F(n.wi) max(0, r.wo)^e0, as in the shader): not reciprocal (measured max relative "
        "asymmetry 0.212 at the defaults, at grazing wo)"
    ),
}


def registry_entries():
    """:class:`brdf_fit.registry.Entry` for the Granier-Heidrich layered RGB BRDF.

    ``expected_failures`` hold values measured with :func:`brdf_fit.checks.run_checks` at the
    defaults (float64; see tests/test_granier_heidrich.py).
    """
    return [
        Entry(
            name="granier-heidrich",
            builder=lambda kd, ks, eta, d, e0, e1: GranierHeidrich(
                kd=kd, ks=ks, eta=eta, d=d, e0=e0, e1=e1),
            params=(
                Param("kd", (0.7, 0.7, 0.7), lo=0.0, hi=1.0, channels=True,
                      doc="diffuse coefficient Kd Cs of the shader"),
                Param("ks", (0.8, 0.8, 0.8), lo=0.0, hi=1.0, channels=True,
                      doc="specular coefficient Ks of the shader"),
                Param("eta", (1.4, 1.45, 1.6), lo=1.0, hi=3.0, channels=True,
                      doc="RGB index of refraction of the layer (layer/outside)"),
                Param("d", 70.0, lo=0.0, hi=1000.0,
                      doc="layer thickness in nm (the diffuse interference phase)"),
                Param("e0", 90.0, lo=0.0, hi=1e4,
                      doc="Phong exponent of the top-surface reflection"),
                Param("e1", 170.0, lo=0.0, hi=1e4,
                      doc="Phong exponent of the base reflection, in refracted directions"),
            ),
            reference=f"{_GH_2003}; as implemented by {_STUART_2002}",
            description=(
                "thin layer over a mirror-like base, per RGB channel: (kd D + ks S)/pi, "
                "S = F(l) max(0, r.v)^e0 + T(l) T(v) max(0, rti.(-to))^e1 in refracted "
                "directions, D = (1 + 2 cos(4 pi eta d/lambda) sqrt(T_d (1 - T_d)))/2, "
                "lambda = 645/525/445 nm"
            ),
            aliases=("granier-heidrich-2003",),
            year=2003,
            catalogue="Granier-Heidrich",
            sampler="cosine fallback (exact pdf)",
            tags=("layered",),
            expected_failures=_GH_FAILURES,
        ),
    ]
