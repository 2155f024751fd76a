"""Independent NumPy/SciPy (float64) reference implementation of microfacet BRDFs.

This module exists only to cross-check the JAX implementation in ``brdf_fit``. It is
deliberately written in a *different* style from a dot-product implementation:

* every direction is first converted to spherical angles ``(theta, phi)`` in the local
  shading frame (z = normal, x = tangent / anisotropy axis, y = bitangent) with
  ``arctan2``; all further quantities are trigonometric functions of these angles;
* the normal distributions D and the Smith ``Lambda`` use the tan(theta) forms of the
  papers;
* the cosine between two directions is obtained from the spherical law of cosines,
  ``cos g = cos t1 cos t2 + sin t1 sin t2 cos(p1 - p2)``;
* the conductor Fresnel term uses complex arithmetic (``numpy.complex128``).

Nothing here imports ``brdf_fit``.

Conventions
-----------
Directions ``wi`` (towards the light) and ``wo`` (towards the viewer) point away from the
surface and have shape ``(..., 3)``, typically ``(N, 3)``. Because only angles are used,
the direction vectors need not be normalised (the angles are scale invariant).
``alpha_x`` is the roughness (slope width) along x, ``alpha_y`` along y.

The BRDF value (1/sr, *without* the cosine factor) is::

    f_r(wi, wo) = F(wo.h) D(h) G2(wi, wo, h) / (4 cos(theta_i) cos(theta_o)),
    h = (wi + wo) / |wi + wo|,

and 0 when ``cos(theta_i) <= 0`` or ``cos(theta_o) <= 0`` (Walter et al. 2007, eq. 20;
Cook & Torrance 1982).

References
----------
* [Walter07] B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet Models for
  Refraction through Rough Surfaces", EGSR 2007.
* [Heitz14] E. Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based
  BRDFs", JCGT 3(2), 2014.
* [TS67] K. Torrance, E. Sparrow, "Theory for Off-Specular Reflection from Roughened
  Surfaces", JOSA 57(9), 1967.
* [CT82] R. Cook, K. Torrance, "A Reflectance Model for Computer Graphics", ACM ToG 1(1),
  1982.
* [BW] M. Born, E. Wolf, "Principles of Optics", Sec. 1.5.2 (Fresnel formulae) and
  Sec. 14.2 (absorbing media, complex refractive index).
* [Schlick94] C. Schlick, "An Inexpensive BRDF Model for Physically-based Rendering",
  Computer Graphics Forum 13(3), 1994.
* [pbrt4] M. Pharr, W. Jakob, G. Humphreys, "Physically Based Rendering", 4th ed.,
  chapter "Reflection Models", Fresnel equations for conductors (``FrComplex``).
"""

from __future__ import annotations

import numpy as np
from scipy.special import erfc

__all__ = [
    "direction",
    "angles",
    "cos_between",
    "ref_D",
    "ref_lambda",
    "ref_G1",
    "ref_G2",
    "ref_fresnel_conductor",
    "ref_fresnel_conductor_polarized",
    "ref_fresnel_dielectric",
    "ref_fresnel_schlick",
    "ref_microfacet_eval",
]

_PI = np.pi
_HALF_PI = 0.5 * np.pi
_DISTS = ("ggx", "beckmann")
_G2_KINDS = ("separable", "height-correlated", "v-cavity")


# ----------------------------------------------------------------------------------------
# Spherical-angle helpers
# ----------------------------------------------------------------------------------------


def direction(theta, phi):
    """Unit vector(s) with polar angle ``theta`` (from +z) and azimuth ``phi`` (from +x).

    Returns an array of shape ``broadcast(theta, phi).shape + (3,)``.
    """
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    st = np.sin(theta)
    return np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), np.cos(theta)), -1)


def angles(w):
    """Spherical angles ``(theta, phi)`` of direction(s) ``w`` (shape ``(..., 3)``).

    ``theta = arctan2(sqrt(x^2 + y^2), z)`` in [0, pi] (more accurate near the pole than
    ``arccos(z)`` and independent of the length of ``w``); ``phi = arctan2(y, x)`` in
    (-pi, pi].
    """
    w = np.asarray(w, dtype=np.float64)
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    theta = np.arctan2(np.hypot(x, y), z)
    phi = np.arctan2(y, x)
    return theta, phi


def cos_between(theta1, phi1, theta2, phi2):
    """Cosine of the angle between two directions given by spherical angles.

    Spherical law of cosines: ``cos g = cos t1 cos t2 + sin t1 sin t2 cos(p1 - p2)``.
    """
    return np.cos(theta1) * np.cos(theta2) + np.sin(theta1) * np.sin(theta2) * np.cos(phi1 - phi2)


def _check_dist(dist):
    d = str(dist).lower()
    if d not in _DISTS:
        raise ValueError(f"unknown distribution {dist!r}; expected one of {_DISTS}")
    return d


# ----------------------------------------------------------------------------------------
# Normal distribution functions
# ----------------------------------------------------------------------------------------


def _D_angles(theta, phi, dist, ax, ay):
    """D(theta_m, phi_m); see :func:`ref_D`."""
    dist = _check_dist(dist)
    ax = np.asarray(ax, dtype=np.float64)
    ay = np.asarray(ay, dtype=np.float64)
    upper = theta < _HALF_PI  # chi+(m . n)
    th = np.where(upper, theta, 0.0)
    tan2 = np.tan(th) ** 2
    cos4 = np.cos(th) ** 4
    # anisotropic "inverse squared roughness" along the azimuth phi_m
    aniso = np.cos(phi) ** 2 / ax**2 + np.sin(phi) ** 2 / ay**2
    if dist == "ggx":
        # Walter07 eq. 33 / Heitz14 eq. 85:
        #   D = 1 / (pi ax ay cos^4 (1 + tan^2 (cos^2/ax^2 + sin^2/ay^2))^2)
        d = 1.0 / (_PI * ax * ay * cos4 * (1.0 + tan2 * aniso) ** 2)
    else:
        # Walter07 eq. 25 / Heitz14 eq. 84:
        #   D = exp(-tan^2 (cos^2/ax^2 + sin^2/ay^2)) / (pi ax ay cos^4)
        d = np.exp(-tan2 * aniso) / (_PI * ax * ay * cos4)
    return np.where(upper, d, 0.0)


def ref_D(m, dist, ax, ay):
    """Microfacet normal distribution D(m) (per unit solid angle of m), shape ``m.shape[:-1]``.

    With ``(theta, phi)`` the spherical angles of ``m``:

    * GGX / Trowbridge-Reitz ([Walter07] eq. 33, anisotropic form [Heitz14] eq. 85)::

        D = 1 / (pi ax ay cos^4 theta (1 + tan^2 theta (cos^2 phi/ax^2 + sin^2 phi/ay^2))^2)

    * Beckmann ([Walter07] eq. 25, anisotropic form [Heitz14] eq. 84)::

        D = exp(-tan^2 theta (cos^2 phi/ax^2 + sin^2 phi/ay^2)) / (pi ax ay cos^4 theta)

    Both include chi+(m . n): D = 0 for theta >= pi/2. Normalised so that
    ``integral D(m) cos(theta_m) d omega_m = 1`` (projected-area normalisation, [Heitz14]).
    """
    theta, phi = angles(m)
    return _D_angles(theta, phi, dist, ax, ay)


# ----------------------------------------------------------------------------------------
# Smith masking
# ----------------------------------------------------------------------------------------


def _projected_roughness(phi, ax, ay):
    """alpha_o = sqrt(cos^2 phi ax^2 + sin^2 phi ay^2)  ([Heitz14] eq. 86)."""
    return np.sqrt(np.cos(phi) ** 2 * np.asarray(ax) ** 2 + np.sin(phi) ** 2 * np.asarray(ay) ** 2)


def _lambda_upper(tan_t, alpha_o, dist, approx):
    """Smith Lambda for directions in the upper hemisphere, tan_t >= 0 (may be +inf).

    ``a = 1 / (alpha_o tan theta)`` ([Heitz14] eqs. 72, 86 with the projected roughness).
    """
    inv_a = alpha_o * tan_t  # 1/a ; 0 at the pole, +inf at the horizon
    if dist == "ggx":
        if approx != "exact":
            raise ValueError("the Walter rational approximation exists only for Beckmann")
        # [Heitz14] eq. 72:  Lambda = (-1 + sqrt(1 + 1/a^2)) / 2, evaluated in the
        # algebraically identical rationalised form x / (2 (1 + sqrt(1 + x))), x = 1/a^2,
        # which has no cancellation when Lambda is small. Gives +inf at the horizon.
        with np.errstate(over="ignore", invalid="ignore"):
            x = inv_a * inv_a
            lam = x / (2.0 * (1.0 + np.sqrt(1.0 + x)))
        return np.where(np.isinf(x), np.inf, lam)
    # Beckmann
    pole = inv_a == 0.0
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        a = np.where(pole, 1.0, 1.0 / inv_a)
        if approx == "exact":
            # [Heitz14] eq. 72 (Beckmann): Lambda = (erf(a) - 1)/2 + exp(-a^2)/(2 a sqrt(pi)).
            # erf(a) - 1 is written as -erfc(a) (same formula, no loss of the small tail).
            lam = -0.5 * erfc(a) + np.exp(-a * a) / (2.0 * a * np.sqrt(_PI))
        elif approx == "walter":
            # [Walter07] eq. 27 rational approximation of G1, rewritten as Lambda = 1/G1 - 1:
            #   Lambda = (1 - 1.259 a + 0.396 a^2) / (3.535 a + 2.181 a^2)  if a < 1.6 else 0
            lam = np.where(
                a < 1.6, (1.0 - 1.259 * a + 0.396 * a * a) / (3.535 * a + 2.181 * a * a), 0.0
            )
        else:
            raise ValueError(f"unknown lambda approximation {approx!r}")
    return np.where(pole, 0.0, lam)


def _lambda_angles(theta, phi, dist, ax, ay, approx="exact"):
    dist = _check_dist(dist)
    alpha_o = _projected_roughness(phi, ax, ay)
    upper = theta <= _HALF_PI  # the horizon itself belongs to the upper side (Lambda = +inf)
    # Evaluate on the mirrored direction (theta -> pi - theta) for the lower hemisphere.
    th = np.where(upper, theta, _PI - theta)
    with np.errstate(over="ignore"):
        tan_t = np.where(th >= _HALF_PI, np.inf, np.tan(th))
    lam = _lambda_upper(tan_t, alpha_o, dist, approx)
    # Back-facing directions: Lambda(-w) = -1 - Lambda(w) ([Heitz14] eq. 72 with a < 0;
    # the Beckmann erf formula satisfies it by oddness of erf).
    return np.where(upper, lam, -1.0 - lam)


def ref_lambda(w, dist, ax, ay, approx="exact"):
    """Smith ``Lambda(w)`` for the anisotropic GGX or Beckmann distribution.

    With ``(theta, phi)`` the spherical angles of ``w``, the projected roughness
    ``alpha_o = sqrt(cos^2 phi ax^2 + sin^2 phi ay^2)`` ([Heitz14] eq. 86) and
    ``a = 1 / (alpha_o tan theta)``:

    * GGX ([Heitz14] eq. 72):        ``Lambda = (-1 + sqrt(1 + 1/a^2)) / 2``
    * Beckmann, ``approx="exact"`` ([Heitz14] eq. 72):
      ``Lambda = (erf(a) - 1)/2 + exp(-a^2) / (2 a sqrt(pi))``
    * Beckmann, ``approx="walter"`` ([Walter07] eq. 27 as 1/G1 - 1):
      ``Lambda = (1 - 1.259 a + 0.396 a^2) / (3.535 a + 2.181 a^2)`` if ``a < 1.6`` else 0.

    ``theta = 0`` gives ``Lambda = 0``; the horizon gives ``+inf``. For back-facing
    directions (``theta > pi/2``) ``Lambda(w) = -1 - Lambda(-w)`` is returned (only of
    interest for transmission; reflection never needs it).
    """
    theta, phi = angles(w)
    return _lambda_angles(theta, phi, dist, ax, ay, approx)


def _G1_angles(theta, phi, dist, ax, ay, approx, cos_wm=None):
    lam = _lambda_angles(theta, phi, dist, ax, ay, approx)
    upper = theta < _HALF_PI
    with np.errstate(divide="ignore"):
        g = np.where(upper, 1.0 / (1.0 + np.where(upper, lam, 0.0)), 0.0)
    if cos_wm is not None:
        g = np.where(cos_wm > 0.0, g, 0.0)  # chi+(w . m)
    return g


def ref_G1(w, dist, ax, ay, m=None, approx="exact"):
    """Smith masking ``G1(w, m) = chi+(w . m) / (1 + Lambda(w))`` ([Heitz14], Smith masking).

    If ``m`` is None the chi+(w . m) factor is omitted (only the "geometric" part
    ``1 / (1 + Lambda(w))``). Directions below the horizon (theta_w >= pi/2) give 0.
    ``w . m`` is computed from the spherical angles of ``w`` and ``m``.
    """
    theta, phi = angles(w)
    cos_wm = None
    if m is not None:
        tm, pm = angles(m)
        cos_wm = cos_between(theta, phi, tm, pm)
    return _G1_angles(theta, phi, dist, ax, ay, approx, cos_wm)


def _G2_angles(ti, pi_, to, po, th, ph, dist, ax, ay, kind, approx):
    """G2 from spherical angles of wi, wo and h."""
    kind = str(kind).lower()
    cos_ih = cos_between(ti, pi_, th, ph)
    cos_oh = cos_between(to, po, th, ph)
    if kind == "separable":
        # uncorrelated Smith: G1(wi, h) G1(wo, h)  ([Walter07] eq. 23; [Heitz14])
        return _G1_angles(ti, pi_, dist, ax, ay, approx, cos_ih) * _G1_angles(
            to, po, dist, ax, ay, approx, cos_oh
        )
    if kind == "height-correlated":
        # chi+(wo.h) chi+(wi.h) / (1 + Lambda(wo) + Lambda(wi))  ([Heitz14] eq. 99)
        ok = (cos_ih > 0.0) & (cos_oh > 0.0) & (ti < _HALF_PI) & (to < _HALF_PI)
        li = _lambda_angles(np.where(ok, ti, 0.0), pi_, dist, ax, ay, approx)
        lo = _lambda_angles(np.where(ok, to, 0.0), po, dist, ax, ay, approx)
        return np.where(ok, 1.0 / (1.0 + li + lo), 0.0)
    if kind == "v-cavity":
        # [TS67], [CT82]:
        #   G = min(1, 2 (n.h)(n.wo)/(wo.h), 2 (n.h)(n.wi)/(wo.h))
        cos_h = np.cos(th)
        ok = (cos_oh > 0.0) & (cos_ih > 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            g_o = 2.0 * cos_h * np.cos(to) / cos_oh
            g_i = 2.0 * cos_h * np.cos(ti) / cos_oh
            g = np.minimum(1.0, np.minimum(g_o, g_i))
        return np.where(ok, np.maximum(g, 0.0), 0.0)
    raise ValueError(f"unknown G2 kind {kind!r}; expected one of {_G2_KINDS}")


def _half_vector(wi, wo):
    s = np.asarray(wi, dtype=np.float64) + np.asarray(wo, dtype=np.float64)
    # the angles of s and of s/|s| coincide, so no normalisation is needed
    return s


def ref_G2(wi, wo, dist, ax, ay, kind, approx="exact"):
    """Masking-shadowing G2(wi, wo, h) with ``h = normalize(wi + wo)``.

    * ``"separable"`` (uncorrelated Smith, [Walter07] eq. 23 / [Heitz14]):
      ``G1(wi, h) G1(wo, h)``;
    * ``"height-correlated"`` ([Heitz14] eq. 99):
      ``chi+(wi.h) chi+(wo.h) / (1 + Lambda(wi) + Lambda(wo))``;
    * ``"v-cavity"`` ([TS67], [CT82]):
      ``min(1, 2 (n.h)(n.wo)/(wo.h), 2 (n.h)(n.wi)/(wo.h))`` (``dist``/roughness unused).
    """
    ti, pi_ = angles(wi)
    to, po = angles(wo)
    th, ph = angles(_half_vector(wi, wo))
    return _G2_angles(ti, pi_, to, po, th, ph, dist, ax, ay, kind, approx)


# ----------------------------------------------------------------------------------------
# Fresnel
# ----------------------------------------------------------------------------------------


def _channel_broadcast(c, *params):
    """Broadcast ``c`` (shape S) against channel parameters (scalar or shape (C,))."""
    c = np.asarray(c, dtype=np.float64)
    params = [np.asarray(p, dtype=np.float64) for p in params]
    params = np.broadcast_arrays(*params)
    if params[0].ndim > 1:
        raise ValueError("channel parameters must be scalars or 1-D arrays")
    if params[0].ndim == 1:
        c = c[..., None]
    return c, params


def ref_fresnel_conductor_polarized(c, eta, k):
    """Fresnel reflectances ``(R_par, R_perp)`` (p- and s-polarised) with complex IOR.

    ``eta_c = eta + i k``, ``c = cos(theta_i)`` ([BW] Sec. 1.5.2 and 14.2; [pbrt4]
    ``FrComplex``)::

        sin^2 t = (1 - c^2) / eta_c^2          (complex Snell)
        cos t   = sqrt(1 - sin^2 t)            (principal branch, numpy complex sqrt)
        r_par   = (eta_c c - cos t) / (eta_c c + cos t)
        r_perp  = (c - eta_c cos t) / (c + eta_c cos t)
        R_par = |r_par|^2, R_perp = |r_perp|^2

    ``c`` is clipped to [0, 1]. Output shape ``c.shape`` for scalar ``eta, k`` or
    ``c.shape + (C,)`` for length-C channel arrays.
    """
    c, (eta, k) = _channel_broadcast(c, eta, k)
    c = np.clip(c, 0.0, 1.0).astype(np.complex128)
    eta_c = eta.astype(np.complex128) + 1j * k.astype(np.complex128)
    sin2_t = (1.0 - c * c) / (eta_c * eta_c)
    cos_t = np.sqrt(1.0 - sin2_t)
    r_par = (eta_c * c - cos_t) / (eta_c * c + cos_t)
    r_perp = (c - eta_c * cos_t) / (c + eta_c * cos_t)
    return np.abs(r_par) ** 2, np.abs(r_perp) ** 2


def ref_fresnel_conductor(c, eta, k):
    """Unpolarised conductor Fresnel ``F = (|r_par|^2 + |r_perp|^2) / 2``.

    See :func:`ref_fresnel_conductor_polarized` ([BW]; [pbrt4] FrComplex).
    """
    r_par, r_perp = ref_fresnel_conductor_polarized(c, eta, k)
    return 0.5 * (r_par + r_perp)


def ref_fresnel_dielectric(c, eta):
    """Dielectric Fresnel reflectance: the complex formula with ``k = 0``.

    For ``eta < 1`` total internal reflection (``sin^2 t > 1``) is handled by the complex
    square root (|r| = 1).
    """
    return ref_fresnel_conductor(c, eta, np.zeros_like(np.asarray(eta, dtype=np.float64)))


def ref_fresnel_schlick(c, f0):
    """Schlick's approximation ``F = f0 + (1 - f0) (1 - c)^5`` ([Schlick94])."""
    c, (f0,) = _channel_broadcast(c, f0)
    c = np.clip(c, 0.0, 1.0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def _fresnel(c, fresnel):
    if fresnel is None:
        return np.ones_like(np.asarray(c, dtype=np.float64))
    kind = str(fresnel[0]).lower()
    if kind == "conductor":
        _, eta, k = fresnel
        return ref_fresnel_conductor(c, eta, k)
    if kind == "dielectric":
        _, eta = fresnel
        return ref_fresnel_dielectric(c, eta)
    if kind == "schlick":
        _, f0 = fresnel
        return ref_fresnel_schlick(c, f0)
    if kind == "none":
        return np.ones_like(np.asarray(c, dtype=np.float64))
    raise ValueError(f"unknown fresnel spec {fresnel!r}")


# ----------------------------------------------------------------------------------------
# Full microfacet BRDF
# ----------------------------------------------------------------------------------------


def ref_microfacet_eval(
    wi,
    wo,
    dist="ggx",
    ax=0.5,
    ay=None,
    g2="height-correlated",
    fresnel=("schlick", 0.04),
    lambda_approx="exact",
):
    """Microfacet reflection BRDF (1/sr, without cosine) ([Walter07] eq. 20; [CT82])::

        f = F(wo.h) D(h) G2(wi, wo, h) / (4 cos theta_i cos theta_o)

    with ``h = normalize(wi + wo)``; ``f = 0`` where ``cos theta_i <= 0`` or
    ``cos theta_o <= 0``.

    Parameters
    ----------
    wi, wo : (..., 3) directions (towards light / viewer) in the local frame.
    dist : ``"ggx"`` or ``"beckmann"``.
    ax, ay : roughness along x and y (``ay=None`` means isotropic, ``ay = ax``); scalars or
        arrays broadcastable to ``wi.shape[:-1]``.
    g2 : ``"separable"``, ``"height-correlated"`` or ``"v-cavity"`` (see :func:`ref_G2`).
    fresnel : ``("conductor", eta, k)``, ``("dielectric", eta)``, ``("schlick", f0)`` or
        ``None`` (F = 1). Parameters are scalars or length-C arrays.
    lambda_approx : ``"exact"`` or ``"walter"`` (Beckmann only), see :func:`ref_lambda`.

    Returns
    -------
    Array of shape ``wi.shape[:-1]`` (scalar Fresnel parameters) or
    ``wi.shape[:-1] + (C,)`` (channel arrays).
    """
    if ay is None:
        ay = ax
    dist = _check_dist(dist)
    ti, pi_ = angles(wi)
    to, po = angles(wo)
    th, ph = angles(_half_vector(wi, wo))

    valid = (ti < _HALF_PI) & (to < _HALF_PI)
    # Replace invalid configurations by a harmless one to avoid spurious inf/nan.
    ti = np.where(valid, ti, 0.0)
    to = np.where(valid, to, 0.0)
    th = np.where(valid, th, 0.0)

    cos_i = np.cos(ti)
    cos_o = np.cos(to)
    cos_oh = cos_between(to, po, th, ph)  # = wo . h = wi . h

    d = _D_angles(th, ph, dist, ax, ay)
    g = _G2_angles(ti, pi_, to, po, th, ph, dist, ax, ay, g2, lambda_approx)
    f_geom = np.where(valid, d * g / (4.0 * cos_i * cos_o), 0.0)

    fr = _fresnel(cos_oh, fresnel)
    if fr.ndim > f_geom.ndim:
        f_geom = f_geom[..., None]
    return fr * f_geom
