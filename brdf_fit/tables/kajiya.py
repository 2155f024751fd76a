"""Kajiya (1985) tables: the Kirchhoff (tangent-plane) scattering of a random Gaussian height
field, computed numerically by FFT over seeded realisations, tabulated for
:class:`brdf_fit.models.kajiya.Kajiya`.

References
----------
- J. T. Kajiya, "Anisotropic reflection models", SIGGRAPH 85, Computer Graphics 19(3):15-21,
  1985 (the Kirchhoff integral over an explicit height field, stored as a reflectance table).
- P. Beckmann, A. Spizzichino, "The Scattering of Electromagnetic Waves from Rough Surfaces",
  Pergamon 1963, ch. 3 (the tangent-plane integral with a constant reflection coefficient and its
  geometric factor F3; ch. 5: the Gaussian surface, the coherent part ``exp(-g)`` and the series
  whose large-``g`` limit is the Beckmann distribution of slopes).
- J. A. Ogilvy, "Theory of Wave Scattering from Random Rough Surfaces", Adam Hilger 1991, ch. 4
  (the same integral in vector form: the scattering vector ``q = k_s - k_i``).
- X. D. He, K. E. Torrance, F. X. Sillion, D. P. Greenberg, SIGGRAPH 1991, eqs. 76-79 (the vector
  geometric factor ``(H.H/H_z)^2`` and ``g``; see :mod:`brdf_fit.models.htsg`).

The form used (derived here; every step is checked numerically by the tests)
---------------------------------------------------------------------------
Directions ``wi``, ``wo`` point away from the surface (toward light and viewer); the wave number is
``k = 2 pi / lambda``, and ``H = wi + wo`` (so the scattering vector is ``q = k H``). With the
reflection coefficient ``R`` taken constant over the patch at its value on the specular facet
(the facet whose normal is ``h = H/|H|``: local angle ``cos = wi.h = |H|/2``; Beckmann &
Spizzichino's approximation, as in He et al.), the tangent-plane integral integrated by parts
(edge terms dropped) gives the far-field amplitude (Beckmann-Spizzichino's ``F3`` times
``cos theta_1``; Ogilvy ch. 4)::

    E_s(wo) = (i k e^{ikr} / (4 pi r)) R (|H|^2 / H_z) I(H),
    I(H)    = Int_A exp(i k (H_x x + H_y y + H_z h(x, y))) dx dy.

(``|H|^2 / H_z = 2 (1 + wi.wo) / (cos_i + cos_o)``: Beckmann-Spizzichino's
``(1 + cos t1 cos t2 - sin t1 sin t2 cos t3) / (cos t1 + cos t2)`` in vector form.) The BRDF is the
radiant intensity per unit projected area and irradiance, ``f = r^2 |E_s|^2 / (A cos_i cos_o)``::

    f(wi, wo) = |R|^2 D_K(H) / (4 cos_i cos_o),
    D_K(H)    = (|H|^2 / H_z)^2 <|I(H)|^2> / (A lambda^2).                                   (K)

``D_K`` depends on the two directions only through ``H``, so (K) is reciprocal as it stands. Its
normalisation is exact and checked: for a flat surface ``|I|^2 -> A (lambda^2) delta(H_xy)``
(Parseval), and ``Int f cos_o dw_o = |R|^2`` (all energy specular, reflectance ``F``). Geometric
optics (``g >> 1``): stationary phase, ``h(r + t) - h(r) ~ s.t`` with ``s`` the local slope, gives
``<|I|^2>/A = lambda^2 p(s) / H_z^2`` at ``s = -H_xy/H_z`` (``p`` the slope density), so
``D_K = |H|^4 p / H_z^4 = p / cos^4 theta_h``: **the microfacet normal distribution D(h)**, and
``f = F D(h) / (4 cos_i cos_o)``, the microfacet BRDF without shadowing. For a Gaussian
correlation ``C(t) = sigma_h^2 exp(-t_x^2/l_x^2 - t_y^2/l_y^2)`` the slopes are Gaussian with
variance ``-C''(0) = 2 sigma_h^2 / l^2`` per axis (RMS slope ``sqrt(2) sigma_h / l``), i.e. the
Beckmann distribution with widths ``alpha_x = 2 sigma_h / l_x``, ``alpha_y = 2 sigma_h / l_y``
(``alpha = sqrt(2)`` times the RMS slope); this is the closed form the tests compare to
(:func:`beckmann_d`, the registry's ``beckmann`` / ``beckmann-aniso`` D), with the widths of the
generated periodic field itself (:attr:`Surface.alpha_x`, from its discrete spectrum).

Wave optics: the ensemble average splits into a coherent and a diffuse part. With
``g = (k sigma_h H_z)^2`` (Beckmann-Spizzichino's ``g``, ``H_z = cos_i + cos_o``),
``<exp(i k H_z h)> = exp(-g/2)``, so a fraction ``exp(-g)`` of ``Int P dH_xy`` (``P`` below) sits
in the specular delta ``H_xy = 0`` (the coherent spike) and ``1 - exp(-g)`` in the diffuse halo.
The tables hold the **diffuse** part only (the coherent part is a delta lobe, left out of ``eval``
as :class:`brdf_fit.models.HTSG` leaves out its ``rho_sp``); :func:`coherent_fraction` gives it.

Numerics
--------
* **Height field** (:func:`height_field`): white noise ``w ~ N(0, 1)`` on an ``n_x x n_y``
  periodic grid of spacing ``dx``, ``h = ifft2(fft2(w) G)`` with ``G = c exp(-(K_x^2 l_x^2 +
  K_y^2 l_y^2)/8)`` (``K`` angular wavenumbers: the square root of the Gaussian correlation's
  spectral density), ``G(0) = 0`` (zero mean) and ``c`` such that ``E[h^2] = mean(G^2) =
  sigma_h^2`` exactly. Array axis 0 is ``x`` (the tangent, the anisotropy axis), axis 1 is ``y``.
  Realisation ``r`` uses ``jax.random.fold_in(PRNGKey(seed), r)``.
* **Spectrum** (:func:`mc_spectrum`): for every tabulated ``zeta = H_z`` (``H_z`` fixes the phase
  factor, so each level is one FFT), ``U = fft2(exp(i k zeta h))``, and ``S = <|U|^2>`` averaged
  over the realisations; ``I(H) = dx^2 U`` at ``H_xy = -lambda f`` with ``f = fftfreq(n, dx)``
  (numpy's sign convention), hence ``P(H) = <|I|^2>/(A lambda^2) = S/N^2`` per FFT cell of area
  ``(lambda/L_x)(lambda/L_y)`` in ``H_xy`` (``N = n_x n_y``; ``sum S / N^2 = 1`` exactly, since
  ``|exp(i k zeta h)| = 1``).
* **Coherent part and lag window** (:func:`diffuse_dk`): the autocorrelation ``A(t) =
  ifft2(S)/N`` (``<u(r + t) u*(r)>`` averaged over ``r`` and realisations) minus its coherent
  constant (``exp(-g)`` in the ensemble; estimated as the mean of ``A`` beyond the window, i.e.
  as realised), multiplied by a lag window ``W`` (1 for ``rho <= LAG_WINDOW_INNER``, a
  cosine taper to 0 at ``LAG_WINDOW_OUTER``, ``rho = sqrt((t_x/l_x)^2 + (t_y/l_y)^2)``), then
  ``fft2`` back. The true diffuse correlation ``exp(-g) (exp(g C/sigma_h^2) - 1)`` is below
  ``g exp(-g) exp(-rho^2)``, i.e. ``< 2e-6`` of its peak beyond ``rho = 3.5`` for every ``g``,
  so the window removes speckle noise (lags where only noise lives) without bias; this is the
  Blackman-Tukey spectral estimate.
* **Exact ensemble reference** (:func:`ensemble_spectrum`): for a Gaussian field the ensemble
  average is known: ``<u(r + t) u*(r)> = exp(-(k zeta)^2 (sigma_h^2 - C_d(t)))`` with the
  discrete periodic correlation ``C_d = ifft2(G^2)``, so ``S_ens = N fft2(...)``: the same
  computation without realisations (no noise). The tests use it to separate Monte Carlo noise
  from physics; it is the Beckmann-Spizzichino series summed by FFT. :func:`diffuse_dk` is linear
  in ``S``, so with the same window the Monte Carlo table's mean is exactly the ensemble table
  (before the log): their difference is noise only. (Without the window the ensemble's zero cell
  ``H_xy = 0`` shows a dip: the zero-mean periodic patch makes ``C_d`` slightly negative at large
  lags, so the coherent constant there is below ``exp(-g)``; the far-lag subtraction removes
  it.)
* **Tables** (:func:`build_table`, :func:`table_from_dk`): ``log D_K`` on ``log H_z`` (uniform,
  ``H_z`` in ``[ZETA_MIN, 2]``) and ``q = (s/alpha)^2``, ``s = H_xy / H_z`` the specular facet's
  slope (``s/alpha`` in ``[0, s_max]``): for the isotropic preset the azimuthal mean over
  ``N_AZIMUTH`` directions (2-D table ``(log_zeta, q)``); for anisotropic ones the mean over the
  four sign combinations ``(+-s_x, +-s_y)`` (3-D table ``(log_zeta, q_x, q_y)``), both by
  bilinear interpolation on the FFT grid. The Gaussian ensemble is invariant under ``x -> -x`` and
  ``y -> -y`` (and rotations when isotropic), so the averages remove noise, not signal; and
  ``D_K`` is a function of ``H = wi + wo``, so the table is **reciprocal by construction**: a
  sample computed for ``(wi, wo)`` is the sample for ``(wo, wi)``.

The heavy part (height fields, phase factors, their FFTs) is jitted JAX (``jnp.fft``) in float64
whatever the global setting; the per-level post-processing is NumPy.

Measured (2-core CPU, float64; tests/models/test_kajiya.py holds the tolerances)
-----------------------------------------------------------------------------
* Geometric optics, ``lambda = 1, sigma_h = 2, l = 8`` (``alpha = 0.507``), ``g = 158, 355,
  632``: the exact ensemble's core RMS difference from Beckmann (``D > 1%`` of the peak) is
  ``0.82/g`` and its peak ratio ``1 + 0.98/g`` (Kirchhoff converges to Beckmann at the rate
  ``1/g``); Monte Carlo: 0.039-0.044 with 32 realisations, 0.016-0.019 with 256 (noise of the
  few FFT cells near the specular slope, ``~ 1/sqrt(2 R)`` each).
* Wave optics, ``sigma_h/lambda = 0.1, 0.2, 0.3``: the measured coherent fraction equals
  ``exp(-g)`` to 2e-3 (16 realisations, ``g = 0.016 .. 14``); the halo differs from the
  Beckmann lobe by 72-156% RMS. Smooth limit (``sigma_h = lambda/1000``):
  :func:`hemisphere_albedo` = ``F`` to 1e-4; all of it coherent.
* Presets, Monte Carlo table against the exact ensemble table: isotropic 0.8-1.4% RMS (max 2.8%)
  for ``H_z >= 0.2``, 3-4% at ``H_z = 0.1``; brushed 2.6-3.6% RMS (max 10%), 6.7% at 0.1.
  Interpolation error of the tables (ensemble tables against ones of twice the resolution in
  every axis, in the lobe core): isotropic RMS 0.17%, max 2.3%; brushed RMS 1.0%, max 8% (at
  small ``H_z``; 0.24%/4.2% for ``H_z >= 0.5``).
* Cost: isotropic 60 s (128 realisations x 48 levels of 512^2 FFTs), brushed 192 s (384 x 32
  levels of 1024 x 256).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import pathlib
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.ndimage import map_coordinates

from brdf_fit.core.table import Axis, Table
from brdf_fit.tables.export import write_table

__all__ = [
    "LAG_WINDOW_INNER",
    "LAG_WINDOW_OUTER",
    "N_AZIMUTH",
    "PRESETS",
    "ZETA_MIN",
    "Surface",
    "beckmann_d",
    "build_table",
    "coherent_fraction",
    "geometric_optics_error",
    "ring_dk",
    "measured_coherent_fraction",
    "D_FLOOR",
    "table_dk",
    "diffuse_dk",
    "ensemble_spectrum",
    "height_field",
    "hemisphere_albedo",
    "mc_spectrum",
    "sample_grid_dk",
    "table_from_dk",
    "write_preset",
]

#: lag window (in correlation lengths): 1 up to INNER, cosine taper to 0 at OUTER. The diffuse
#: correlation is < 2e-6 of its peak beyond rho = 3.5 (module docstring), so INNER = 3.5 loses
#: nothing; OUTER = 5 must stay below half the patch (checked in :func:`diffuse_dk`)
LAG_WINDOW_INNER = 3.5
LAG_WINDOW_OUTER = 5.0
#: smallest tabulated H_z = cos_i + cos_o: below it both directions are within ~6 degrees of the
#: horizon, where the tangent-plane approximation is invalid anyway (models.md 4.11); the model
#: clamps H_z to it (edge value)
ZETA_MIN = 0.1
#: azimuths of the isotropic ring average
N_AZIMUTH = 256
#: floor of the tabulated D_K before its log (1/sr): the presets' peaks are 3-7, so this is
#: < 1e-10 of the peak (Beckmann D at s = 4.8 alpha); Monte Carlo noise in the far tail can make
#: the windowed estimate <= 0 there, which the floor absorbs
D_FLOOR = 1e-10


@dataclasses.dataclass(frozen=True)
class Surface:
    """A Gaussian random height field and its sampling grid (lengths in micrometres; only ratios
    to the wavelength matter)."""

    name: str
    wavelength: float
    sigma_h: float
    l_x: float
    l_y: float
    n_x: int
    n_y: int
    #: grid spacing. The phase exp(i k H_z h) has local frequency H_z s / lambda (s the local
    #: slope), so the spectrum sits at H_xy = -H_z s; lambda/6 puts the Nyquist limit at
    #: |H_xy| = 3 (period 6), so content aliases only from |H_xy| > 4 (H_z s > 4, i.e. slopes
    #: beyond 2, 3.9 alpha_y of the roughest preset axis) onto reachable |H_xy| <= 2
    dx: float
    realisations: int
    seed: int
    n_zeta: int = 20
    #: nodes of each q = (s/alpha)^2 axis on [0, s_max^2]
    n_slope: int = 49
    #: table range of s/alpha (Beckmann D at 6 alpha: exp(-36) of the peak)
    s_max: float = 6.0

    @property
    def alpha_x(self) -> float:
        """Beckmann width along x of the generated field: ``sqrt(2)`` x its RMS slope, from its
        discrete spectrum (``2 sigma_h / l_x`` for the continuous Gaussian correlation; the
        periodic patch without its zero mode has a slightly larger slope variance: +1.4% in
        ``alpha`` at ``L = 10.7 l``, +0.4% at ``L = 20 l``, measured)."""
        return _realised_alphas(self)[0]

    @property
    def alpha_y(self) -> float:
        return _realised_alphas(self)[1]

    @property
    def alpha_nominal(self) -> tuple[float, float]:
        """``(2 sigma_h / l_x, 2 sigma_h / l_y)``: the continuous Gaussian surface's widths."""
        return 2.0 * self.sigma_h / self.l_x, 2.0 * self.sigma_h / self.l_y

    @property
    def isotropic(self) -> bool:
        return self.l_x == self.l_y

    @property
    def k(self) -> float:
        return 2.0 * math.pi / self.wavelength

    def g(self, zeta):
        """Beckmann-Spizzichino's ``g = (k sigma_h H_z)^2`` at ``H_z = zeta``."""
        return (self.k * self.sigma_h * np.asarray(zeta, dtype=np.float64)) ** 2

    def zetas(self) -> np.ndarray:
        """The tabulated ``H_z``: uniform in ``log H_z`` on ``[ZETA_MIN, 2]`` (``g`` grows like
        ``H_z^2``, and the lobe changes fastest where ``g ~ 1``, i.e. at small ``H_z``)."""
        return np.exp(np.linspace(math.log(ZETA_MIN), math.log(2.0), self.n_zeta))

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.update(alpha_x=self.alpha_x, alpha_y=self.alpha_y,
                 alpha_nominal=list(self.alpha_nominal))
        return d


_LAM = 0.55
#: the model's presets (micrometres). isotropic: alpha = 2 sigma_h/l = 1/3; g = 20.9 H_z^2, so
#: the lobe is Beckmann-like near the normal (g = 84 at H_z = 2) and wave-optical near grazing
#: (g = 0.8 at H_z = 0.2); patch 512^2 x lambda/6 = 46.9 um = 19.6 l. brushed: grooves along x
#: (long l_x), alpha_x = 0.1, alpha_y = 0.5; patch 1024 x 256 -> 93.9 x 23.5 um = 11.7 l_x x
#: 14.7 l_y. Table sizes: (48, 97) and (32, 65, 65) float64 (43 kB and 1.1 MB files)
PRESETS: dict[str, Surface] = {
    "isotropic": Surface("isotropic", _LAM, 0.4, 2.4, 2.4, 512, 512, _LAM / 6, 128, 1985,
                         n_zeta=48, n_slope=97),
    "brushed": Surface("brushed", _LAM, 0.4, 8.0, 1.6, 1024, 256, _LAM / 6, 384, 1985,
                       n_zeta=32, n_slope=65),
}


# ----------------------------------------------------------------------------- height fields


def _filter(s: Surface) -> np.ndarray:
    kx = 2.0 * np.pi * np.fft.fftfreq(s.n_x, s.dx)[:, None]
    ky = 2.0 * np.pi * np.fft.fftfreq(s.n_y, s.dx)[None, :]
    G = np.exp(-(kx**2 * s.l_x**2 + ky**2 * s.l_y**2) / 8.0)
    G[0, 0] = 0.0
    return G * (s.sigma_h / np.sqrt(np.mean(G * G)))


@functools.cache
def _realised_alphas(s: Surface) -> tuple[float, float]:
    G = _filter(s)
    kx = 2.0 * np.pi * np.fft.fftfreq(s.n_x, s.dx)[:, None]
    ky = 2.0 * np.pi * np.fft.fftfreq(s.n_y, s.dx)[None, :]
    return (float(np.sqrt(2.0 * np.mean(G * G * kx * kx))),
            float(np.sqrt(2.0 * np.mean(G * G * ky * ky))))


def height_field(s: Surface, r: int = 0) -> np.ndarray:
    """Realisation ``r`` of the surface (``(n_x, n_y)`` float64 heights; module docstring)."""
    key = jax.random.fold_in(jax.random.PRNGKey(s.seed), r)
    return np.asarray(_height(key, jnp.asarray(_filter(s))))


@jax.jit
def _height(key, G):
    w = jax.random.normal(key, G.shape, dtype=jnp.float64)
    return jnp.fft.ifft2(jnp.fft.fft2(w) * G.astype(jnp.complex128)).real


@jax.jit
def _phase_spectra(key, G, kzeta):
    h = _height(key, G)
    p = kzeta[:, None, None] * h[None]
    u = jax.lax.complex(jnp.cos(p), jnp.sin(p))  # exp(i k zeta h)
    U = jnp.fft.fft2(u)
    return (U.real * U.real + U.imag * U.imag)


def mc_spectrum(s: Surface, zetas=None, realisations: int | None = None,
                progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """``S = <|fft2(exp(i k zeta h))|^2>`` over realisations ``0..R-1``, shape
    ``(len(zetas), n_x, n_y)`` (unshifted FFT order), float64. ``progress(done, total)`` is
    called after each realisation."""
    with jax.enable_x64(True):
        zetas = s.zetas() if zetas is None else np.asarray(zetas, dtype=np.float64)
        R = s.realisations if realisations is None else int(realisations)
        G = jnp.asarray(_filter(s))
        kz = jnp.asarray(s.k * zetas)
        base = jax.random.PRNGKey(s.seed)
        acc = None
        for r in range(R):
            S = _phase_spectra(jax.random.fold_in(base, r), G, kz)
            acc = S if acc is None else acc + S
            if progress is not None:
                progress(r + 1, R)
        return np.asarray(acc) / R


def ensemble_spectrum(s: Surface, zetas=None) -> np.ndarray:
    """The exact ensemble mean of :func:`mc_spectrum` for the periodic Gaussian field (module
    docstring): ``N fft2(exp(-(k zeta)^2 (sigma_h^2 - C_d)))``, same shape and order."""
    zetas = s.zetas() if zetas is None else np.asarray(zetas, dtype=np.float64)
    G = _filter(s)
    C = np.fft.ifft2(G * G).real
    var = C[0, 0]
    N = s.n_x * s.n_y
    out = np.empty((len(zetas), s.n_x, s.n_y))
    for j, z in enumerate(zetas):
        A = np.exp(-(s.k * z) ** 2 * (var - C))
        out[j] = N * np.fft.fft2(A).real
    return out


def coherent_fraction(s: Surface, zeta):
    """``exp(-g)``: the fraction of ``Int P dH_xy`` in the coherent (specular) delta."""
    return np.exp(-s.g(zeta))


def measured_coherent_fraction(s: Surface, S: np.ndarray) -> np.ndarray:
    """The coherent fraction of a computed spectrum ``S`` (one value per level): the mean of
    the autocorrelation ``ifft2(S)/N`` at lags beyond the lag window (``rho >
    LAG_WINDOW_OUTER`` correlation lengths), where the diffuse correlation has died out, so what
    remains is ``|<u>|^2`` (Beckmann-Spizzichino: ``exp(-g)``)."""
    far = _lag_window(s) == 0.0
    N = s.n_x * s.n_y
    return np.array([np.mean((np.fft.ifft2(Sj) / N)[far].real) for Sj in S])


# ----------------------------------------------------------------------------- D_K


def _lag_window(s: Surface) -> np.ndarray:
    tx = np.fft.fftfreq(s.n_x, 1.0 / s.n_x)[:, None] * s.dx
    ty = np.fft.fftfreq(s.n_y, 1.0 / s.n_y)[None, :] * s.dx
    rho = np.sqrt((tx / s.l_x) ** 2 + (ty / s.l_y) ** 2)
    t = np.clip((rho - LAG_WINDOW_INNER) / (LAG_WINDOW_OUTER - LAG_WINDOW_INNER), 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * t))


def _h_grid(s: Surface):
    """``H_x``, ``H_y`` of the FFT cells (unshifted order): ``H = -lambda f``."""
    hx = -s.wavelength * np.fft.fftfreq(s.n_x, s.dx)
    hy = -s.wavelength * np.fft.fftfreq(s.n_y, s.dx)
    return hx, hy


def diffuse_dk(s: Surface, S: np.ndarray, zetas=None, window: bool = True) -> np.ndarray:
    """``D_K`` of the diffuse part (eq. (K) of the module docstring) times the FFT cell area in
    ``H_xy``, on the fftshifted FFT grid (index ``i`` holds ``H_x = lambda (n_x/2 - i)/L_x``;
    :func:`sample_grid_dk` maps ``H`` to indices and divides by the cell area)."""
    zetas = s.zetas() if zetas is None else np.asarray(zetas, dtype=np.float64)
    N = s.n_x * s.n_y
    if window and min(s.n_x * s.dx / s.l_x, s.n_y * s.dx / s.l_y) < 2.0 * LAG_WINDOW_OUTER:
        raise ValueError(f"{s.name}: the patch must span 2 x {LAG_WINDOW_OUTER} correlation "
                         "lengths for the lag window")
    W = _lag_window(s) if window else None
    hx, hy = _h_grid(s)
    H2xy = hx[:, None] ** 2 + hy[None, :] ** 2
    out = np.empty_like(S)
    far = (_lag_window(s) == 0.0) if window else None
    for j, z in enumerate(zetas):
        A = np.fft.ifft2(S[j]) / N
        if W is not None:
            # the coherent constant as realised (its mean beyond the window, where the true
            # diffuse correlation is < 1e-10), not its ensemble value exp(-g): the realisations'
            # own coherent power fluctuates about exp(-g), and subtracting the ensemble value
            # would leave that fluctuation as a spurious bump at H_xy = 0
            A = (A - np.mean(A[far].real)) * W
        else:
            A = A - np.exp(-s.g(z))
        Sd = N * np.fft.fft2(A).real
        geo = ((H2xy + z * z) / z) ** 2
        # per FFT cell: (|H|^2/H_z)^2 times the cell's share S/N^2 of Int P dH_xy / lambda^2
        out[j] = np.fft.fftshift(geo * Sd / (N * N))
    return out


def sample_grid_dk(s: Surface, dk: np.ndarray, zetas, hx, hy):
    """Bilinear interpolation of the fftshifted ``dk`` (one slice per ``zeta``) at ``H_xy``
    points ``hx``, ``hy`` (arrays of shape ``(len(zetas), ...)``). ``P`` per unit ``H_xy``
    is ``S/N^2`` per cell of area ``(lambda/L_x)(lambda/L_y)``; the value returned is the density
    ``D_K`` (eq. (K)): cell value divided by the cell area in ``H_xy``."""
    cell = (s.wavelength / (s.n_x * s.dx)) * (s.wavelength / (s.n_y * s.dx))
    # H = -lambda f, f = (i - n/2)/(n dx)  =>  i = n/2 - H n dx / lambda
    ix = s.n_x // 2 - np.asarray(hx) * s.n_x * s.dx / s.wavelength
    iy = s.n_y // 2 - np.asarray(hy) * s.n_y * s.dx / s.wavelength
    out = np.empty(np.shape(hx))
    for j in range(len(zetas)):
        out[j] = np.asarray(map_coordinates(jnp.asarray(dk[j]), [jnp.asarray(ix[j]),
                                                                 jnp.asarray(iy[j])],
                                            order=1, mode="constant", cval=0.0))
    return out / cell


def beckmann_d(sx, sy, alpha_x, alpha_y):
    """The closed form: Beckmann D as a function of the slope ``s = -H_xy/H_z``,
    ``D = exp(-(s_x/a_x)^2 - (s_y/a_y)^2) (1 + s^2)^2 / (pi a_x a_y)`` (``1/cos^4 theta_h =
    (1 + s^2)^2``; Beckmann-Spizzichino 1963; Walter et al. 2007 eq. 25)."""
    s2 = sx * sx + sy * sy
    return np.exp(-(sx / alpha_x) ** 2 - (sy / alpha_y) ** 2) * (1.0 + s2) ** 2 / (
        np.pi * alpha_x * alpha_y)


def table_from_dk(s: Surface, dk: np.ndarray, meta: dict | None = None) -> Table:
    """The model's table from ``D_K`` on the fftshifted FFT grid at ``s.zetas()`` (module
    docstring: ring average when isotropic, four-quadrant average otherwise).

    Axes: ``log_zeta = log H_z`` and ``q = (s/alpha)^2`` (per axis when anisotropic) on
    ``[0, s_max^2]``; channel ``log_D_K = log(max(D_K, D_FLOOR))``. In these coordinates the
    geometric-optics limit (Beckmann) is ``log D = -q_x - q_y + 2 log(1 + s^2) + const``: linear
    in each ``q`` but for the slowly varying ``log(1 + s^2)``, so multilinear interpolation is
    nearly exact for it, and the lobe stays smooth through ``s = 0`` (no kink at the mirror
    direction)."""
    zetas = s.zetas()
    q = np.linspace(0.0, s.s_max**2, s.n_slope)
    u = np.sqrt(q)
    z = zetas[:, None, None]
    if s.isotropic:
        vals = ring_dk(s, dk, zetas, u)
        axes = (Axis("log_zeta", math.log(ZETA_MIN), math.log(2.0), s.n_zeta, centres=False),
                Axis("q", 0.0, s.s_max**2, s.n_slope, centres=False))
    else:
        hx0 = u[None, :, None] * s.alpha_x * z
        hy0 = u[None, None, :] * s.alpha_y * z
        hx0, hy0 = np.broadcast_arrays(hx0, hy0)
        vals = 0.0
        for sgx in (1.0, -1.0):
            for sgy in (1.0, -1.0):
                vals = vals + sample_grid_dk(s, dk, zetas, sgx * hx0, sgy * hy0)
        vals = vals / 4.0
        axes = (Axis("log_zeta", math.log(ZETA_MIN), math.log(2.0), s.n_zeta, centres=False),
                Axis("q_x", 0.0, s.s_max**2, s.n_slope, centres=False),
                Axis("q_y", 0.0, s.s_max**2, s.n_slope, centres=False))
    m = {"model": "kajiya", "surface": s.to_dict(), "d_floor": D_FLOOR, **(meta or {})}
    logd = np.log(np.maximum(np.asarray(vals, dtype=np.float64), D_FLOOR))
    return Table(logd[..., None], axes, ("log_D_K",), m)


def ring_dk(s: Surface, dk: np.ndarray, zetas, u) -> np.ndarray:
    """Azimuthal mean of ``D_K`` (from :func:`diffuse_dk`) on rings of slope ``|s| = u alpha``,
    shape ``(len(zetas), len(u))`` (isotropic surfaces)."""
    zetas = np.asarray(zetas, dtype=np.float64)
    phi = (np.arange(N_AZIMUTH) + 0.5) * (2.0 * np.pi / N_AZIMUTH)
    r = np.asarray(u)[None, :, None] * s.alpha_x * zetas[:, None, None]
    hx = np.broadcast_to(r * np.cos(phi)[None, None, :], (len(zetas), len(u), N_AZIMUTH))
    hy = np.broadcast_to(r * np.sin(phi)[None, None, :], hx.shape)
    return sample_grid_dk(s, dk, zetas, hx, hy).mean(axis=-1)


def geometric_optics_error(s: Surface, S: np.ndarray, zetas, core: float = 0.01,
                           n_u: int = 64, alpha: float | None = None
                           ) -> tuple[np.ndarray, np.ndarray]:
    """``(rms, peak)`` per level: the relative RMS difference between the ring-averaged diffuse
    ``D_K`` of spectrum ``S`` and the closed-form Beckmann ``D`` of the field's widths, over the
    lobe core (``D > core`` x its peak: ``u = s/alpha <= sqrt(log(1/core))``), and the ratio
    ``D_K/D`` at the specular slope ``s = 0`` (isotropic surfaces). ``alpha`` replaces the
    closed form's width (negative controls)."""
    u = np.linspace(0.0, np.sqrt(np.log(1.0 / core)), n_u)
    v = ring_dk(s, diffuse_dk(s, S, zetas), zetas, u)
    a = s.alpha_x if alpha is None else float(alpha)
    B = beckmann_d(u * s.alpha_x, 0.0 * u, a, a)
    return np.sqrt(np.mean((v / B[None, :] - 1.0) ** 2, axis=1)), v[:, 0] / B[0]


def table_dk(table: Table, zeta, qx, qy=None) -> np.ndarray:
    """``D_K`` from a table (NumPy/JAX lookup, ``exp`` of the interpolated log), 0 beyond the
    slope range."""
    if len(table.axes) == 2:
        qq = qx if qy is None else qx + qy
        v = np.exp(np.asarray(table.lookup(np.log(zeta), qq))[..., 0])
        return np.where(qq <= table.axes[1].hi, v, 0.0)
    v = np.exp(np.asarray(table.lookup(np.log(zeta), qx, qy))[..., 0])
    return np.where((qx <= table.axes[1].hi) & (qy <= table.axes[2].hi), v, 0.0)


def build_table(s: Surface, progress: Callable[[int, int], None] | None = None,
                ensemble: bool = False) -> Table:
    """The table of preset surface ``s``: Monte Carlo over ``s.realisations`` realisations
    (``ensemble=True``: from the exact ensemble spectrum instead, for comparison)."""
    t0 = time.perf_counter()
    S = ensemble_spectrum(s) if ensemble else mc_spectrum(s, progress=progress)
    dk = diffuse_dk(s, S)
    table = table_from_dk(s, dk, {"source": "ensemble" if ensemble else "monte-carlo",
                                  "seconds": round(time.perf_counter() - t0, 2)})
    return table


def hemisphere_albedo(s: Surface, S: np.ndarray, zetas, cos_i: float, F: float = 1.0,
                      coherent: bool = True) -> float:
    """``Int f cos_o dw_o`` over the upper hemisphere straight from the FFT cells for ``wi =
    (sin t, 0, cos t)``, ``cos t = cos_i`` (no table): each cell ``H_xy`` is the direction
    ``wo_xy = H_xy - wi_xy`` with ``cos_o = sqrt(1 - |wo_xy|^2)``, its spectrum taken at
    ``zeta = cos_i + cos_o`` by linear interpolation between the levels; ``f cos_o dw_o = F
    (|H|^2/H_z)^2 S/N^2 / (4 cos_i cos_o)`` per cell (``dw_o = dH_xy / cos_o``; at the mirror
    direction the factor is 1, so a flat surface gives ``F``). With ``coherent``
    the coherent part is kept (``S`` as computed); the smooth limit gives ``F``."""
    zetas = np.asarray(zetas, dtype=np.float64)
    N = s.n_x * s.n_y
    hx, hy = _h_grid(s)
    sin_i = math.sqrt(max(0.0, 1.0 - cos_i * cos_i))
    ox = hx[:, None] - sin_i
    oy = np.broadcast_to(hy[None, :], (s.n_x, s.n_y))
    r2 = ox * ox + oy * oy
    up = r2 < 1.0
    cos_o = np.sqrt(np.where(up, 1.0 - r2, 0.0))
    zeta = cos_i + cos_o
    j = np.clip(np.searchsorted(zetas, zeta) - 1, 0, len(zetas) - 2)
    t = np.clip((zeta - zetas[j]) / (zetas[j + 1] - zetas[j]), 0.0, 1.0)
    ii, jj = np.indices((s.n_x, s.n_y))
    Sz = (1.0 - t) * S[j, ii, jj] + t * S[j + 1, ii, jj]
    if not coherent:
        Sz = Sz - np.where((ii == 0) & (jj == 0), N * N * np.exp(-s.g(zeta)), 0.0)
    H2 = hx[:, None] ** 2 + hy[None, :] ** 2 + zeta * zeta
    val = F * (H2 / zeta) ** 2 * Sz / (N * N) / (4.0 * cos_i * np.where(up, cos_o, 1.0))
    return float(np.sum(np.where(up, val, 0.0)))


def write_preset(name: str, directory, progress=None) -> list:
    """Compute the preset's table and write ``kajiya_<name>.npz`` (+ ``.json``) into
    ``directory`` (the package ships ``brdf_fit/resources/tables``)."""
    table = build_table(PRESETS[name], progress=progress)
    return write_table(table, pathlib.Path(directory) / f"kajiya_{name}.npz")
