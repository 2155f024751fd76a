"""Test-side quadrature over wi in the half-vector parameterisation, with the horizon cut exact.

For a fixed ``wo`` the map ``h -> wi = reflect(wo, h)`` is a bijection from the half vectors with
``wo.h > 0`` to all directions, with ``dw_i = 4 (wo.h) dw_h`` (Walter et al. 2007, eq. 14). The
upper hemisphere of ``wi`` corresponds to ``tan(theta_h) < t_max(phi_h)`` where
``cos_o t^2 - 2 sin_o cos(phi_h - phi_o) t - cos_o = 0``; integrating only there puts the
discontinuity of every pdf at the horizon on the boundary of the domain.
"""

import numpy as np


def halfvector_rule(wo, beta, n_v=256, n_phi=256):
    """Directions ``wi`` (N, 3) in the upper hemisphere and solid-angle weights (N,) such that
    ``sum w g(wi) ~ Int_{H+} g(wi) dw_i`` for integrands concentrated around the mirror direction
    with half-vector lobe width ``beta`` (the microfacet alpha)."""
    wo = np.asarray(wo, float)
    st = np.hypot(wo[0], wo[1])
    ct = wo[2]
    phi_o = np.arctan2(wo[1], wo[0])
    x, w = np.polynomial.legendre.leggauss(n_v)
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    c = np.cos(phi - phi_o)
    tmax = (st * c + np.sqrt((st * c) ** 2 + ct * ct)) / ct
    # tan(theta) = beta * s/(1 - s), s in [0, s_max]
    qmax = tmax / beta
    smax = qmax / (1 + qmax)
    s = 0.5 * (x[None, :] + 1) * smax[:, None]
    ws = 0.5 * w[None, :] * smax[:, None]
    q = s / (1 - s)
    th = np.arctan(beta * q)
    dth = beta / (1 + (beta * q) ** 2) / (1 - s) ** 2
    P = np.broadcast_to(phi[:, None], th.shape)
    h = np.stack([np.sin(th) * np.cos(P), np.sin(th) * np.sin(P), np.cos(th)], -1)
    wh = ws * dth * np.sin(th) * (2 * np.pi / n_phi)
    d = h @ wo
    wi = 2 * d[..., None] * h - wo
    weights = wh * 4 * d
    wi = wi.reshape(-1, 3)
    wi[:, 2] = np.maximum(wi[:, 2], 1e-300)  # round-off at the cut: stay in the upper hemisphere
    return wi, weights.reshape(-1)


def gauss_hemisphere(n_mu=128, n_phi=128):
    """Plain Gauss-Legendre in cos(theta) x trapezoid in phi (smooth integrands)."""
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mu = 0.5 * (x + 1)
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    M, P = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - M * M)
    d = np.stack([s * np.cos(P), s * np.sin(P), M], -1).reshape(-1, 3)
    wt = (0.5 * w[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]).reshape(-1)
    return d, wt
