"""Beard-Maxwell BRDF (Maxwell, Beard, Weiner, Ladd & Ladd 1973), in the form of the NEF database
as presented by Westlund & Meyer (2002).

Sources: J. R. Maxwell, J. Beard, S. Weiner, D. Ladd, S. Ladd, "Bidirectional reflectance model
validation and utilization", Technical Report AFAL-TR-73-303, Environmental Research Institute of
Michigan, 1973 (not available to us); H. B. Westlund, G. W. Meyer, "A BRDF database employing
the Beard-Maxwell reflection model", Graphics Interface 2002, pp. 189-200 (the form used by the
NEFDS; its full text was not available to us either). The formula below is Westlund-Meyer's
equation 10 as transcribed by the one public implementation that names it (a DIRSIG-based
Python example, ``radiometry.py`` ``beard_maxwell``) and by models.md 4.5; the structure
(Fresnel ratio, ``cos^2 theta_N/(cl cv)``, the shadowing/obscuration factor, the two volume terms)
agrees with PiscisRT ``PRTMaterial.cpp`` (``BRDF_BM``) and with the Montes & Urena (2012) summary::

    f = [R(beta)/R(0)] rho_fs(theta_N) cos^2(theta_N)/(cl cv) SO(theta_N, beta)
        + rho_D + 2 rho_V/(cl + cv)
    SO = (1 + (theta_N/Omega) exp(-2 beta/tau)) / (1 + theta_N/Omega)
       = (Omega + theta_N exp(-2 beta/tau)) / (Omega + theta_N)         (form used here)

``theta_N`` = angle between the normal and the half vector ``h`` (the facet tilt), ``beta`` =
angle between ``l`` and ``h`` (half the phase angle), ``R`` = unpolarised Fresnel reflectance of
the complex index ``n - i k`` (:func:`brdf_fit.fresnel.conductor`; the sign of ``k`` does not
change it), ``R(0) = ((n-1)^2 + k^2)/((n+1)^2 + k^2)``: two Fresnel evaluations per call.

Conventions and how far each is pinned:

* ``rho_fs`` (**not pinned to the paper**): ``rho_fs = B exp(-(theta_N/sigma)^2)`` (``fs_form=
  "gaussian"``, the transcription of Westlund-Meyer eq. 10 in the Python implementation; used by
  the registry entry). models.md also reports a Lorentzian NEFDS form ``B/(4 cos^3 theta_N
  (sigma^2 + tan^2 theta_N))`` (UNVERIFIED there), available as ``fs_form="lorentzian"``.
  PiscisRT uses a constant ``rho_fs``.
* ``rho_D``, ``rho_V`` are BRDF values in 1/sr (added as they stand, as in the Python
  implementation), not reflectances: the albedo of ``rho_D`` is ``pi rho_D`` and that of the
  volume term ``4 pi rho_V [1 - cv ln(1 + 1/cv)]`` (``4 pi (1 - ln 2) rho_V`` at normal
  incidence, ``-> 4 pi rho_V`` at grazing). PiscisRT instead divides the whole sum by ``pi``.
* ``tau`` and ``Omega`` are in **radians** here (the library's unit; the Python implementation
  and NEF files give degrees: convert at the file boundary). PiscisRT's defaults are
  ``Omega = 0.4``, ``tau = 0.15`` (radians), which we adopt.
* The Fresnel ratio uses ``beta`` (``cos beta = l.h``), as in Westlund-Meyer and the Python code;
  PiscisRT uses the plain ``F(beta)`` without dividing by ``R(0)``.
* **Calibration**: with ``B`` a free amplitude the form needs no normalisation. NEF materials
  declare a directional-hemispherical reflectance instead of ``B``; :meth:`BeardMaxwell.
  first_surface_albedo_normal` integrates the first-surface term at normal incidence by a fixed
  Gauss-Legendre rule in JAX (differentiable in every parameter), so ``B = DHR / albedo(B = 1)``
  (:func:`calibrate_b`) reproduces the Python implementation's ``dhr_specular_scale``.
* At ``n = 1, k = 0`` (``R(0) = 0``: no interface) the ratio is 0/0; the first-surface term is
  then 0 (its value for every other index is finite).

Reciprocal (``theta_N``, ``beta``, ``cl cv`` and ``cl + cv`` are symmetric). Not energy
conserving: the ``1/(cl cv)`` makes the first-surface albedo grow like ``1/cv`` at grazing views
(measured in :func:`registry_entries`). Angles are computed without ``acos``:
``theta_N = atan2(|h_xy|, h_z)``, ``beta = atan2(|l - v|, |l + v|)`` with zero-gradient norms at
0 (``|l - v| = 2 sin beta``, ``|l + v| = 2 cos beta``), so ``l = v`` and the normal are safe.

Sampling (fallback, no analytic sampler; Westlund & Meyer tabulate and use the alias method):
with probability ``p_c = 0.1 + 0.8 A_vol/(A_vol + A_fs)`` a cosine-weighted direction, else a
Beckmann half-vector lobe of width ``alpha = sigma`` about the mirror direction
(``exp(-(theta_N/sigma)^2) ~ exp(-tan^2(theta_N)/sigma^2)`` for small tilts); ``A_vol = pi max
rho_D + 4 pi (1 - ln 2) max rho_V``, ``A_fs = 4 pi sigma^2 B`` (the small-sigma first-surface
albedo at normal incidence). ``pdf`` is the exact mixture density; lobe samples with ``v.m <= 0``
or below the horizon fail.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.fresnel import conductor, f0_from_ior
from brdf_fit.core.numerics import INV_PI, safe_div, safe_sqrt
from brdf_fit.core.params import Channels, Entry, Param, Scalar, bounded
from brdf_fit.core.validate import ParameterError, check_param, check_scalar
from brdf_fit.models._base import AbstractBRDF, QuadratureLobe, expand_channels
from brdf_fit.models._fallback import cosine_beckmann_pdf, cosine_beckmann_sample
from brdf_fit.models._lobes import sanitize_pair, upper

__all__ = ["BeardMaxwell", "calibrate_b", "registry_entries"]

_FS_FORMS = ("gaussian", "lorentzian")
#: clamp of the sampling lobe's Beckmann width
SAMPLER_ALPHA_MIN = 1e-3
#: Gauss-Legendre nodes per panel of the normal-incidence albedo rule (two panels in the tilt t:
#: [0, min(pi/4, 6 sigma)] and the rest; the Gaussian lobe is below 1e-15 of its peak at 6 sigma)
ALBEDO_NODES = 64

_BM = (
    "J. R. Maxwell, J. Beard, S. Weiner, D. Ladd, S. Ladd, Bidirectional reflectance model "
    "validation and utilization, AFAL-TR-73-303, ERIM 1973; form of H. B. Westlund, G. W. Meyer, "
    "A BRDF database employing the Beard-Maxwell reflection model, Graphics Interface 2002 "
    "(eq. 10, Gaussian rho_fs as transcribed by a public DIRSIG-based implementation)"
)


def _norm_zero_grad(x, y, z):
    """``sqrt(x^2 + y^2 + z^2)`` with value and gradient 0 at the origin."""
    return safe_sqrt(x * x + y * y + z * z)


class BeardMaxwell(AbstractBRDF):
    """Beard-Maxwell / NEF BRDF (see the module docstring). ``eta``, ``k`` (index ``n - i k``),
    ``rho_d`` and ``rho_v`` (1/sr) may carry channels; ``b``, ``sigma`` (radians), ``tau``
    (radians), ``omega`` (radians) are scalars."""

    b: Scalar = bounded(2.0, lo=0.0)
    sigma: Scalar = bounded(0.1, lo=0.0, hi=0.5 * math.pi, lo_open=True)
    tau: Scalar = bounded(0.15, lo=0.0, lo_open=True)
    omega: Scalar = bounded(0.4, lo=0.0, lo_open=True)
    eta: Channels = bounded(1.65, lo=0.0, lo_open=True, channels=True)
    k: Channels = bounded(0.0, lo=0.0, channels=True)
    rho_d: Channels = bounded(0.05, lo=0.0, hi=INV_PI, channels=True)
    rho_v: Channels = bounded(0.01, lo=0.0, hi=0.25 * INV_PI, channels=True)
    fs_form: str = eqx.field(static=True, default="gaussian")

    def __check_init__(self):
        owner = "BeardMaxwell"
        if self.fs_form not in _FS_FORMS:
            raise ParameterError(f"{owner}: fs_form must be one of {_FS_FORMS}, got "
                                 f"{self.fs_form!r}")
        check_param("b", self.b, lo=0.0, owner=owner)
        for name in ("sigma", "tau", "omega"):
            check_param(name, getattr(self, name), lo=0.0, lo_open=True, owner=owner)
        for name in ("b", "sigma", "tau", "omega"):
            check_scalar(name, getattr(self, name), owner)
        check_param("eta", self.eta, lo=0.0, lo_open=True, owner=owner)
        check_param("k", self.k, lo=0.0, owner=owner)
        check_param("rho_d", self.rho_d, lo=0.0, owner=owner)
        check_param("rho_v", self.rho_v, lo=0.0, owner=owner)

    # ------------------------------------------------------------------ pieces

    def _rho_fs(self, cos_n, theta_n):
        if self.fs_form == "gaussian":
            return self.b * jnp.exp(-(theta_n / self.sigma) ** 2)
        # B/(4 cos^3 (sigma^2 + tan^2)) = B cos^-1 / (4 (sigma^2 cos^2 + sin^2))
        c2 = cos_n * cos_n
        return self.b * safe_div(1.0, 4.0 * cos_n * (self.sigma ** 2 * c2 + (1.0 - c2)))

    def _first_surface(self, cos_n, theta_n, beta, cos_beta):
        """``[R(beta)/R(0)] rho_fs cos^2(theta_N) SO`` (without the ``1/(cl cv)``)."""
        ch = self.channels()
        E = lambda x: expand_channels(x, ch)  # noqa: E731
        R = conductor(E(cos_beta), self.eta, self.k)
        R0 = f0_from_ior(self.eta, self.k)
        ratio = safe_div(R, R0)
        so = (self.omega + theta_n * jnp.exp(-2.0 * beta / self.tau)) / (self.omega + theta_n)
        return ratio * E(self._rho_fs(cos_n, theta_n) * cos_n * cos_n * so)

    def first_surface(self, wi, wo):
        """The first-surface term alone (1/sr), 0 below the horizon."""
        valid, (ix, iy, iz), (ox, oy, oz) = sanitize_pair(wi, wo)
        Hx, Hy, Hz = ix + ox, iy + oy, iz + oz
        Hn = _norm_zero_grad(Hx, Hy, Hz)  # 2 cos(beta) > 0 on valid lanes
        Dn = _norm_zero_grad(ix - ox, iy - oy, iz - oz)  # 2 sin(beta)
        beta = jnp.arctan2(Dn, Hn)
        hxy = _norm_zero_grad(Hx, Hy, 0.0)
        theta_n = jnp.arctan2(hxy, Hz)
        cos_n = Hz / Hn
        cos_beta = jnp.minimum(0.5 * Hn, 1.0)
        ch = self.channels()
        fs = self._first_surface(cos_n, theta_n, beta, cos_beta)
        val = fs * expand_channels(safe_div(1.0, iz * oz), ch)
        return jnp.where(expand_channels(valid, ch), val, 0.0)

    def eval(self, wi, wo):
        iz, oz = wi[..., 2], wo[..., 2]
        valid = upper(wi, wo)
        ch = self.channels()
        s = jnp.where(valid, iz + oz, 1.0)
        vol = self.rho_d + 2.0 * self.rho_v * expand_channels(1.0 / s, ch)
        val = self.first_surface(wi, wo) + vol
        return jnp.where(expand_channels(valid, ch), val, 0.0)

    def first_surface_albedo_normal(self):
        """Directional-hemispherical reflectance of the first-surface term at normal incidence,
        ``4 pi Int_0^(pi/4) [R(t)/R(0)] rho_fs(t) cos^2(t) SO(t, t) sin(2t) dt`` (``l = n``: the
        tilt and ``beta`` both equal half the polar angle of ``v``), by a fixed two-panel
        Gauss-Legendre rule (:data:`ALBEDO_NODES` per panel); differentiable in every
        parameter."""
        x, w = np.polynomial.legendre.leggauss(ALBEDO_NODES)
        dt = jnp.result_type(self.b, self.sigma, self.tau, self.omega)
        x, w = jnp.asarray(x, dt), jnp.asarray(w, dt)
        quarter = 0.25 * math.pi
        cut = jnp.minimum(quarter, 6.0 * self.sigma)
        t1 = 0.5 * cut * (x + 1.0)
        w1 = 0.5 * cut * w
        t2 = cut + 0.5 * (quarter - cut) * (x + 1.0)
        w2 = 0.5 * (quarter - cut) * w
        t = jnp.concatenate([t1, t2])
        wt = jnp.concatenate([w1, w2])
        fs = self._first_surface(jnp.cos(t), t, t, jnp.cos(t))
        integrand = fs * expand_channels(jnp.sin(2.0 * t) * wt, self.channels())
        return 4.0 * math.pi * jnp.sum(integrand, axis=0)

    # ------------------------------------------------------------------ sampling

    def _sampler_alpha(self):
        return jnp.clip(self.sigma, SAMPLER_ALPHA_MIN, 1.0)

    def _p_cos(self):
        a_vol = (math.pi * jnp.max(jnp.asarray(self.rho_d))
                 + 4.0 * math.pi * (1.0 - math.log(2.0)) * jnp.max(jnp.asarray(self.rho_v)))
        a_fs = 4.0 * math.pi * self.sigma ** 2 * self.b
        return 0.1 + 0.8 * safe_div(a_vol, a_vol + a_fs)

    def pdf(self, wi, wo):
        return cosine_beckmann_pdf(wi, wo, self._sampler_alpha(), self._p_cos())

    def sample(self, wo, uc, u):
        return cosine_beckmann_sample(self, wo, uc, u, self._sampler_alpha(), self._p_cos())

    def quadrature_lobe(self) -> QuadratureLobe:
        """Quadrature hint (:func:`brdf_fit.verify.albedo.lobe_rule`): a half-vector lobe of the
        first-surface width ``sigma``."""
        return QuadratureLobe("half", self._sampler_alpha())

    def selection_hint(self):
        return (math.pi * jnp.max(jnp.asarray(self.rho_d))
                + 4.0 * math.pi * jnp.max(jnp.asarray(self.rho_v))
                + 4.0 * math.pi * self.sigma ** 2 * self.b)


def calibrate_b(dhr, **params):
    """``B`` such that the first-surface term reflects ``dhr`` at normal incidence (the NEF
    calibration; ``params`` are the other :class:`BeardMaxwell` fields). Differentiable."""
    unit = BeardMaxwell(b=1.0, **params)
    return dhr / unit.first_surface_albedo_normal()


# ----------------------------------------------------------------------------- registry

# Measured with brdf_fit.checks.run_checks("beard-maxwell") at the defaults (float64).
_BM_FAILURES: dict[str, str] = {
    "energy": (
        "the first-surface term's 1/(cl cv) (Westlund-Meyer eq. 10) makes the albedo grow like "
        "1/cv at grazing views: measured E = 69.8 (blue channel) at cos_o = 1e-3, 8.2 at 1e-2, "
        "1.48 at 0.2; 0.545 at normal view. NEF data are calibrated at normal incidence only"
    ),
}


def registry_entries():
    """The ``beard-maxwell`` entry (Gaussian rho_fs, angles in radians, rho_D and rho_V in 1/sr)."""
    return [
        Entry(
            name="beard-maxwell",
            builder=lambda b, sigma, tau, omega, eta, k, rho_d, rho_v: BeardMaxwell(
                b=b, sigma=sigma, tau=tau, omega=omega, eta=eta, k=k, rho_d=rho_d, rho_v=rho_v),
            params=(
                Param("b", 2.0, lo=0.0, doc="first-surface amplitude B of rho_fs (1/sr)"),
                Param("sigma", 0.1, lo=0.0, hi=0.5 * math.pi, lo_open=True,
                      doc="width of the Gaussian rho_fs in the facet tilt (radians)"),
                Param("tau", 0.15, lo=0.0, lo_open=True,
                      doc="shadowing decay constant tau (radians of beta)"),
                Param("omega", 0.4, lo=0.0, lo_open=True,
                      doc="obscuration constant Omega (radians of facet tilt)"),
                Param("eta", (1.65, 1.6, 1.55), lo=0.0, lo_open=True, channels=True,
                      doc="real part n of the index n - ik (paint binder ~1.65)"),
                Param("k", (0.2, 0.2, 0.2), lo=0.0, channels=True,
                      doc="extinction coefficient k of the index n - ik"),
                Param("rho_d", (0.08, 0.06, 0.04), lo=0.0, hi=INV_PI, channels=True,
                      doc="Lambertian volume term rho_D (1/sr; albedo pi rho_D)"),
                Param("rho_v", (0.02, 0.015, 0.01), lo=0.0, hi=0.25 * INV_PI, channels=True,
                      doc="directional volume term rho_V (1/sr; albedo <= 4 pi rho_V)"),
            ),
            reference=_BM,
            description=(
                "Beard-Maxwell / NEF: [R(beta)/R(0)] B exp(-(theta_N/sigma)^2) cos^2(theta_N) "
                "SO/(cl cv) + rho_D + 2 rho_V/(cl + cv), complex Fresnel of n - ik"
            ),
            aliases=("nef", "beard-maxwell-nef"),
            expected_failures=_BM_FAILURES,
            year=1973,
            catalogue="Beard-Maxwell",
            sampler="cosine + Beckmann half-vector mixture (exact pdf)",
        ),
    ]
