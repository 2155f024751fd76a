"""Split-sum DFG tables of GGX: ``A(mu, r)`` and ``B(mu, r)``, exact to quadrature error.

With Schlick's Fresnel ``F = F0 + (1 - F0)(1 - wo.h)^5`` the directional albedo of a GGX lobe is
linear in ``F0`` (Karis 2013, "Real Shading in Unreal Engine 4", SIGGRAPH course notes, the
"environment BRDF" of the split-sum approximation):

    E(mu) = F0 A(mu, alpha) + B(mu, alpha),
    A = Int D V (1 - (1 - wo.h)^5) cos(theta_i) dwi,   B = Int D V (1 - wo.h)^5 cos(theta_i) dwi,

with ``V = G2 / (4 cos(theta_i) cos(theta_o))``, ``D`` the GGX normal distribution and
``mu = cos(theta_o)``. ``A + B`` is the albedo with ``F = 1`` (the white furnace; 1 minus the
single-scattering energy loss).

**Quadrature.** Each texel is integrated with :func:`brdf_fit.core.quadrature.halfvector_rule`,
whose domain ends exactly at the horizon (the integrand jumps to 0 there, which is where sampling
estimators lose accuracy) and whose nodes follow the lobe down to any width; the whole table is
computed in float64 whatever the global JAX setting (``jax.enable_x64`` around the computation).
The integrand is written in slope space (``t^2 = tan^2(theta_h)`` from ``wi + wo``), so the
GGX density ``D = alpha^2 / (pi cos^4(theta_h) (alpha^2 + t^2)^2)`` keeps full relative precision
for ``alpha`` far below ``ALPHA_MIN`` (e.g. ``alpha = 1.5e-5`` on the first row of a 128-texel
table): nothing is clamped.

**The limits.** ``alpha = 0`` (the first row of an endpoint layout) is the mirror: every masking
term tends to 1, so ``A = 1 - (1 - mu)^5`` and ``B = (1 - mu)^5`` in closed form. ``mu = 0`` (the
first column of an endpoint layout) is the one-sided limit ``mu -> 0+`` (the view on the horizon
has no solid angle of its own), evaluated at ``mu = MU_LIMIT_REL * alpha``.

**Accuracy** (48 x 64 nodes against 192 x 256, float64, measured for every masking): below 1e-7
for ``alpha >= 1e-5`` at every ``mu`` including the limit, and for ``mu >= 1e-2`` at every
``alpha``; where both are tiny (``alpha < 1e-5`` with ``mu < 1e-4``, e.g. ``alpha = 1e-6``,
``mu = 1e-6``: 2e-6) the rule's float64 construction loses accuracy. Every table's
``error_estimate`` includes its first row and column, so such a table says so.

**Masking** (``masking=``):

* ``"height-correlated"``: ``G2 = 1 / (1 + Lambda(wi) + Lambda(wo))``, GGX ``Lambda`` (Heitz 2014,
  "Understanding the masking-shadowing function in microfacet-based BRDFs", JCGT 3(2), eq. 99 and
  eq. 72); Filament and the Khronos glTF sample viewer.
* ``"separable"``: ``G2 = G1(wi) G1(wo)`` (Walter et al. 2007, eq. 23 with eq. 34).
* ``"karis"``: Schlick-Smith ``G1(w) = cos / (cos (1 - k) + k)`` with ``k = alpha / 2`` (Karis
  2013, the remapping used for image-based lighting in UE4; Schlick 1994 form of G1),
  separable.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit._version import __version__
from brdf_fit.core.quadrature import HALFVECTOR_N_PHI, HALFVECTOR_N_THETA, halfvector_rule
from brdf_fit.core.table import Axis, Table
from brdf_fit.tables._stream import run_blocks

__all__ = [
    "DFG_MASKINGS",
    "MU_LIMIT_REL",
    "block_size",
    "dfg_reference_texel",
    "dfg_table",
    "dfg_values",
]

#: the masking-shadowing terms a DFG table can be built with (see the module docstring)
DFG_MASKINGS = ("height-correlated", "separable", "karis")

#: the column ``mu = 0`` is the limit ``mu -> 0+``, evaluated at ``mu = MU_LIMIT_REL * alpha``.
#: For small widths ``E`` depends on ``mu / alpha`` only (the horizon is then a straight line at
#: ``mu / (2 alpha)`` lobe widths from the lobe centre) and approaches its limit linearly in
#: ``mu / alpha``; measured slope 14 at ``alpha = 1`` (height-correlated: ``1 - E = 1.4e-5`` at
#: ``mu = 1e-6``) and 0.2 for ``alpha <= 1e-2``, so 1e-10 puts the limit within 1.4e-9.
MU_LIMIT_REL = 1e-10

#: texels integrated per compiled call at the default order (48 x 64 nodes; other orders get
#: ``BLOCK * 3072 / (n_theta * n_phi)`` texels, at least :data:`MIN_BLOCK`, so a block holds about
#: the same number of nodes). Small blocks keep a call's intermediates (``BLOCK * 1536`` nodes x 8
#: bytes = 0.8 MB per array) in the 2-4 MB per-core cache: measured on 2 cores (load 1.8), a
#: 128 x 128 table on one thread took 0.82 s in blocks of 64 against 1.50 s in blocks of 256 and
#: 1.68 s in blocks of 2048 (the former default), the same work; on two threads 0.76 s. Memory:
#: ``WINDOW_PER_WORKER * cores`` blocks live (tables._stream).
BLOCK = 64
#: the fewest texels per call (high orders): per-call overhead (~50 us) stays small
MIN_BLOCK = 8


def _visibility(masking: str, alpha, ix, iy, iz, co, so, sqrt=jnp.sqrt):
    """``V = G2 / (4 cos_i cos_o)`` for GGX of width ``alpha`` with ``wo = (so, 0, co)``
    (``sqrt=math.sqrt``: on Python floats, for the SciPy reference)."""
    a2 = alpha * alpha
    if masking == "karis":
        k = 0.5 * alpha
        return 0.25 / ((iz * (1.0 - k) + k) * (co * (1.0 - k) + k))
    # P(w) = cos(theta) (1 + 2 Lambda(w)) = sqrt(z^2 + alpha^2 (x^2 + y^2)) (Heitz 2014, eq. 72)
    p_i = sqrt(iz * iz + a2 * (ix * ix + iy * iy))
    p_o = sqrt(co * co + a2 * so * so)
    if masking == "height-correlated":
        return 0.5 / (co * p_i + iz * p_o)
    if masking == "separable":
        return 1.0 / ((iz + p_i) * (co + p_o))
    raise ValueError(f"unknown masking {masking!r}; choose one of {', '.join(DFG_MASKINGS)}")


@functools.partial(jax.jit, static_argnames=("masking", "n_theta", "n_phi"))
def _dfg_block(mu, alpha, masking: str, n_theta: int, n_phi: int):
    """``(A, B)`` for texels ``(mu[k], alpha[k])`` with ``alpha > 0`` and ``mu > 0`` (float64).

    **Mirror symmetry.** With ``wo`` in the xz-plane the integrand is even in ``wi.y`` and the
    isotropic :func:`~brdf_fit.core.quadrature.halfvector_rule` is mirror-symmetric about that
    plane, ray for ray: its last ``n_phi / 2`` rays are the mirror images (``wi.y -> -wi.y``) of
    its first ``n_phi / 2``, node for node with equal weights (lobe-centred pole: chords at the
    trapezoid angles ``chi`` and ``2 pi - chi``; pole on the horizon: panels at ``psi`` and
    ``-psi``, the lobe direction ``psi_L`` being exactly 0 in the plane of incidence). At
    ``mu = 1`` the view has no azimuth and the rule's pole may sit at any azimuth; its halves then
    mirror about that pole's vertical plane, which the rotationally symmetric integrand (a
    function of ``wi.z`` only) respects as well. So the integral is twice the sum over the first
    half: the same rule, half the integrand evaluations (equal to the full sum to ~1e-14;
    tests/tables/test_dfg.py checks the layout that this relies on)."""
    so = jnp.sqrt(jnp.maximum(1.0 - mu * mu, 0.0))
    wo = jnp.stack([so, jnp.zeros_like(mu), mu], axis=-1)
    rule = halfvector_rule(wo, alpha, n_theta=n_theta, n_phi=n_phi, dtype=jnp.float64)
    k = mu.shape[0]
    half = n_phi // 2
    dirs = rule.directions.reshape(k, n_phi, n_theta, 3)[:, :half].reshape(k, half * n_theta, 3)
    w = 2.0 * rule.weights.reshape(k, n_phi, n_theta)[:, :half].reshape(k, half * n_theta)
    ix, iy, iz = (dirs[..., c] for c in range(3))
    a, co, so_ = alpha[:, None], mu[:, None], so[:, None]
    # half vector from the unnormalised sum (no cancellation in its tangent components)
    hx, hy, hz = ix + so_, iy, iz + co
    t2 = (hx * hx + hy * hy) / (hz * hz)  # tan^2(theta_h)
    s2 = hx * hx + hy * hy + hz * hz
    cos_h2 = hz * hz / s2
    a2 = a * a
    d = a2 / (math.pi * cos_h2 * cos_h2 * (a2 + t2) ** 2)  # GGX D (Walter et al. 2007, eq. 33)
    v = _visibility(masking, a, ix, iy, iz, co, so_)
    f_cos = d * v * iz
    woh = 0.5 * jnp.sqrt(s2)  # wo.h = |wi + wo| / 2 for unit wi, wo
    s5 = (1.0 - woh) ** 5
    b = jnp.sum(w * f_cos * s5, axis=-1)
    e = jnp.sum(w * f_cos, axis=-1)
    return e - b, b


def block_size(n_theta: int, n_phi: int) -> int:
    """Texels per compiled call for a rule of ``n_theta x n_phi`` nodes (see :data:`BLOCK`)."""
    return max(MIN_BLOCK, (BLOCK * HALFVECTOR_N_THETA * HALFVECTOR_N_PHI) // (n_theta * n_phi))


def dfg_values(mu, alpha, masking: str = "height-correlated", *,
               n_theta: int = HALFVECTOR_N_THETA, n_phi: int = HALFVECTOR_N_PHI,
               block: int | None = None, progress: Callable[[int, int], None] | None = None,
               workers: int | None = None):
    """``A, B`` (float64 NumPy, shape of ``broadcast(mu, alpha)``) at arbitrary points.

    ``alpha = 0`` uses the closed-form mirror limit, ``mu = 0`` the limit ``mu -> 0+`` (module
    docstring). Texels are streamed through one compiled function in blocks of ``block`` texels
    (default :func:`block_size`) on ``workers`` threads (default: every usable core), so memory
    does not grow with the number of texels beyond the outputs. ``progress(done, total)`` is
    called after each block of texels."""
    if masking not in DFG_MASKINGS:
        raise ValueError(f"unknown masking {masking!r}; choose one of {', '.join(DFG_MASKINGS)}")
    if n_phi % 2 or n_phi < 4:
        raise ValueError(f"n_phi must be even and >= 4, got {n_phi}")
    mu, alpha = np.broadcast_arrays(np.asarray(mu, np.float64), np.asarray(alpha, np.float64))
    if np.any(~np.isfinite(mu)) or np.any(mu < 0) or np.any(mu > 1):
        raise ValueError("mu must lie in [0, 1]")
    if np.any(~np.isfinite(alpha)) or np.any(alpha < 0):
        raise ValueError("alpha must be finite and >= 0")
    block = block_size(n_theta, n_phi) if block is None else int(block)
    shape = mu.shape
    al_f = alpha.ravel()
    mu_f = mu.ravel()
    mu_f = np.where(mu_f > 0, mu_f, MU_LIMIT_REL * al_f)
    A = np.empty(mu_f.shape)
    B = np.empty(mu_f.shape)
    mirror = al_f == 0.0
    A[mirror] = 1.0 - (1.0 - mu_f[mirror]) ** 5
    B[mirror] = (1.0 - mu_f[mirror]) ** 5
    todo = np.flatnonzero(~mirror)
    total = todo.size
    # pad to the block size, or a small call to a power of two (>= 16): one compilation serves
    # every table of a given order and masking, and small calls share a few
    width = block if total > block else max(16, 1 << max(total - 1, 0).bit_length())

    def compute(start: int, stop: int) -> None:
        idx = todo[start:stop]
        pad = width - idx.size
        m_blk = np.concatenate([mu_f[idx], np.full(pad, 0.5)])
        a_blk = np.concatenate([al_f[idx], np.full(pad, 0.5)])
        a_out, b_out = _dfg_block(jnp.asarray(m_blk), jnp.asarray(a_blk), masking, n_theta,
                                  n_phi)
        A[idx] = np.asarray(a_out)[:idx.size]
        B[idx] = np.asarray(b_out)[:idx.size]

    run_blocks(compute, total, width, progress=progress, workers=workers)
    return A.reshape(shape), B.reshape(shape)


def dfg_reference_texel(mu: float, alpha: float, masking: str = "height-correlated",
                        *, epsabs: float = 1e-12) -> tuple[float, float]:
    """``A, B`` at one texel by adaptive SciPy quadrature in ``(theta_h, phi_h)`` (an independent
    check of :func:`dfg_values`; needs SciPy). The half-vector substitution
    ``dwi = 4 (wo.h) dw_h`` (Walter et al. 2007, eq. 14) with the horizon as the limit of the
    inner integral: for a half vector at ``(theta_h, phi_h)``, ``wi.z = 2 (wo.h) cos(theta_h) -
    mu``; the inner integral over ``theta_h`` is split at the lobe width and stopped where
    ``wi.z`` changes sign (found by ``brentq``)."""
    from scipy import integrate, optimize

    so, co = math.sqrt(max(1.0 - mu * mu, 0.0)), mu
    a2 = alpha * alpha

    def parts(th, ph):
        st, ct = math.sin(th), math.cos(th)
        hx, hy, hz = st * math.cos(ph), st * math.sin(ph), ct
        woh = so * hx + co * hz
        if woh <= 0:
            return 0.0, 0.0
        ix, iy, iz = 2 * woh * hx - so, 2 * woh * hy, 2 * woh * hz - co
        if iz <= 0:
            return 0.0, 0.0
        t2 = (st / ct) ** 2
        d = a2 / (math.pi * ct**4 * (a2 + t2) ** 2)
        v = float(_visibility_np(masking, alpha, ix, iy, iz, co, so))
        f = d * v * iz * 4.0 * woh * st  # f cos * Jacobian * sin(theta_h) (solid angle)
        s5 = (1.0 - woh) ** 5
        return f * (1.0 - s5), f * s5

    def theta_max(ph):
        # wi.z(theta_h) = 2 (wo.h) cos(theta_h) - mu decreases through 0 once on [0, pi/2)
        def g(th):
            return 2 * (so * math.sin(th) * math.cos(ph) + co * math.cos(th)) * math.cos(th) - co
        hi = 0.5 * math.pi - 1e-15
        return optimize.brentq(g, 0.0, hi, xtol=1e-15) if g(hi) < 0 else hi

    out = []
    for k in range(2):
        def inner(ph, k=k):
            tmax = theta_max(ph)
            lobe = min(math.atan(alpha) * 8, tmax)
            pts = [0.0, math.atan(alpha), lobe, tmax]
            pts = sorted({p for p in pts if 0.0 <= p <= tmax})
            val = 0.0
            for lo, hi in zip(pts[:-1], pts[1:], strict=False):
                if hi > lo:
                    val += integrate.quad(lambda th: parts(th, ph)[k], lo, hi, epsabs=epsabs,
                                          epsrel=1e-12, limit=200)[0]
            return val
        # symmetric in phi_h about the plane of incidence
        out.append(2.0 * integrate.quad(inner, 0.0, math.pi, epsabs=epsabs, epsrel=1e-12,
                                        limit=200)[0])
    return out[0], out[1]


def _visibility_np(masking, alpha, ix, iy, iz, co, so):
    """:func:`_visibility` on Python floats (float64, no JAX dispatch: the SciPy reference calls
    it ~10^6 times; through JAX each reference texel took 40-110 s)."""
    return _visibility(masking, float(alpha), float(ix), float(iy), float(iz), float(co),
                       float(so), sqrt=math.sqrt)


def dfg_table(size: int = 128, masking: str | None = None, *, layout=None,
              n_theta: int = HALFVECTOR_N_THETA, n_phi: int = HALFVECTOR_N_PHI,
              error_estimate: bool = True, progress=None) -> Table:
    """The split-sum table ``(A, B)`` on a ``size x size`` grid of the layout (default: texel
    centres, rows = perceptual roughness ``r = (j + 0.5)/size`` with ``alpha = r^2``, columns =
    ``mu = (i + 0.5)/size``), as a :class:`~brdf_fit.core.table.Table` with axes
    ``('roughness', 'mu')`` and the layout's channels (``('A', 'B')`` by default).
    ``masking`` defaults to the layout's (height-correlated for all but ``ue4``).

    ``error_estimate``: the table's metadata gets ``error_estimate`` = the largest difference, on
    a subgrid of up to 16 x 16 texels that includes the first and last row and column, between
    this rule and one with twice the nodes in each direction (the quadrature error of the
    coarser rule is far larger than that of the finer, so this estimates it)."""
    from brdf_fit.tables.layouts import resolve_layout

    lay = resolve_layout(layout)
    masking = lay.masking if masking is None else masking
    if not isinstance(size, int) or size < 2:
        raise ValueError(f"table size must be an integer >= 2, got {size!r}")
    if masking not in DFG_MASKINGS:
        raise ValueError(f"unknown masking {masking!r}; choose one of {', '.join(DFG_MASKINGS)}")
    ax_r = Axis("roughness", 0.0, 1.0, size, lay.centres)
    ax_mu = Axis("mu", 0.0, 1.0, size, lay.centres)
    r = ax_r.nodes()
    alpha = r * r if lay.roughness_axis == "r" else r
    mu = ax_mu.nodes()
    t0 = time.perf_counter()
    A, B = dfg_values(mu[None, :], alpha[:, None], masking, n_theta=n_theta, n_phi=n_phi,
                      progress=progress)
    seconds = time.perf_counter() - t0
    meta = {
        "kind": "dfg",
        "masking": masking,
        "layout": lay.to_dict(),
        "roughness_axis": lay.roughness_axis,
        "quadrature": {"rule": "halfvector_rule", "n_theta": n_theta, "n_phi": n_phi,
                       "evaluations_per_texel": n_theta * n_phi, "dtype": "float64"},
        "limits": {"alpha=0": "closed form (mirror)",
                   "mu=0": f"evaluated at mu={MU_LIMIT_REL} alpha"},
        "seconds": round(seconds, 3),
        "brdf_fit_version": __version__,
    }
    if error_estimate:
        k = np.unique(np.linspace(0, size - 1, min(size, 16)).round().astype(int))
        A2, B2 = dfg_values(mu[None, k], alpha[k, None], masking, n_theta=2 * n_theta,
                            n_phi=2 * n_phi)
        err = np.maximum(np.abs(A2 - A[np.ix_(k, k)]), np.abs(B2 - B[np.ix_(k, k)]))
        meta["error_estimate"] = {
            "max_abs": float(err.max()),
            "method": f"max(|dA|, |dB|) against {2 * n_theta}x{2 * n_phi} nodes on a "
                      f"{k.size}x{k.size} subgrid of texels",
            "rows": k.tolist(),
            "columns": k.tolist(),
            "per_texel": [[float(f"{x:.3g}") for x in row] for row in err],
        }
    planes = {"A": A, "B": B, "E": A + B}
    return Table(np.stack([planes[c] for c in lay.channels], axis=-1), (ax_r, ax_mu),
                 lay.channels, meta)
