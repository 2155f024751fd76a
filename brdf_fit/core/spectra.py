"""Tabulated optical constants of metals, spectral Fresnel reflectance and its linear-sRGB colour.

The complex refractive index ``n + i k`` of eight bulk metals (Ag, Al, Au, Cr, Cu, Fe, Ni, Ti) is
shipped as CSV files in ``brdf_fit/resources/nk`` (columns ``wavelength_um, n, k``; the comment
lines at the top of each file name its source, see :func:`source`). From them this module computes

- the spectral conductor reflectance at any angle (:func:`spectral_reflectance`, JAX, through
  :func:`brdf_fit.fresnel.conductor`);
- its colour as linear sRGB under illuminant D65 (:func:`spectrum_to_rgb`,
  :func:`reflectance_rgb`; a NumPy data-preparation path, not differentiated);
- an effective per-channel index ``(eta_rgb, k_rgb)`` whose RGB conductor Fresnel reproduces that
  colour over the whole angular range (:func:`rgb_nk`, :func:`rgb_nk_fit_error`), which is what
  :func:`conductor_fresnel` uses in ``"rgb"`` mode.

References
----------
- P. B. Johnson, R. W. Christy, "Optical constants of the noble metals", Phys. Rev. B 6,
  4370-4379 (1972), doi:10.1103/PhysRevB.6.4370 (Ag, Au, Cu).
- P. B. Johnson, R. W. Christy, "Optical constants of transition metals: Ti, V, Cr, Mn, Fe, Co,
  Ni, and Pd", Phys. Rev. B 9, 5056-5070 (1974), doi:10.1103/PhysRevB.9.5056 (Cr, Fe, Ni, Ti).
- A. D. Rakic, "Algorithm for the determination of intrinsic optical constants of metal films:
  application to aluminum", Appl. Opt. 34, 4755-4767 (1995), doi:10.1364/AO.34.004755 (Al).
- The tables were taken from the refractiveindex.info database (M. N. Polyanskiy), CC0 1.0.
- CIE 1931 2 degree standard colorimetric observer (ISO/CIE 11664-1; the 1 nm table of the CVRL
  database) and CIE standard illuminant D65 (ISO/CIE 11664-2; 5 nm table), both as shipped with
  colour-science.
- IEC 61966-2-1:1999, sRGB default RGB colour space (primaries, D65 white point, the XYZ-to-RGB
  matrix); only the linear part is used, never the transfer function.
- T. Mansencal et al., colour-science (Colour), https://www.colour-science.org,
  doi:10.5281/zenodo.3757045: colour matching functions, illuminant tables, integration and the
  XYZ-to-RGB conversion.
- O. Gulbrandsen, "Artist friendly metallic Fresnel", JCGT 3(4), 2014: the (reflectivity,
  edge tint) -> (n, k) map used to start the :func:`rgb_nk` fit.
"""

from __future__ import annotations

import functools
import importlib.resources

import colour
import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.fresnel import ConductorFresnel, conductor

__all__ = [
    "materials",
    "source",
    "load_nk",
    "default_wavelengths",
    "nk_at",
    "spectral_reflectance",
    "spectrum_to_rgb",
    "reflectance_rgb",
    "rgb_nk",
    "rgb_nk_fit_error",
    "conductor_fresnel",
    "R_CLIP",
]

#: Integration grid of :func:`spectrum_to_rgb`: 1 nm steps over the range where both the CIE 1931
#: colour matching functions (360-830 nm) and the CIE D65 table (300-780 nm) are defined.
_CIE_START_NM, _CIE_END_NM, _CIE_STEP_NM = 360.0, 780.0, 1.0

#: Number of cosines at which :func:`rgb_nk` fits, and the denser check grid of
#: :func:`rgb_nk_fit_error` (uniform in cos, both ends included, distinct from the fit nodes).
_FIT_NODES = 64
_CHECK_POINTS = 257

#: Box for the fitted effective indices (eta and k alike). A conductor reflects at most 1, but the
#: linear-sRGB colour of a saturated metal can exceed 1 in one channel (gold's red does); the
#: least-squares optimum is then at infinity (F = 1 everywhere) and the box keeps the parameters
#: finite and usable in float32 (``conductor`` is accurate there up to k = 100 and beyond).
_NK_MIN, _NK_MAX = 1e-3, 1e2
#: Out-of-gamut channels (linear-sRGB reflectance above 1 somewhere, gold's red: 1.037 at normal
#: incidence) are clipped to this reflectance before the fit, so that the fit ends at a real
#: conductor inside the box (gold's red: F(1) = R_CLIP with finite eta, k) instead of at the box
#: corner (eta = 1e-3, k = 100: F = 1 - 5e-7 at every angle, issue 16). 0.995 is the largest
#: normal reflectance among the tabulated metals' in-gamut channels (silver's red, 0.989) plus
#: a margin; a channel clipped here reports its excess in :func:`rgb_nk_fit_error`.
R_CLIP = 0.995


#: One compiled kernel per input shape instead of op-by-op dispatch (much faster to warm up).
_conductor_jit = jax.jit(conductor)


def _nk_dir():
    return importlib.resources.files("brdf_fit") / "resources" / "nk"


@functools.lru_cache(maxsize=1)
def materials() -> tuple[str, ...]:
    """Names of the tabulated metals (chemical symbols, e.g. ``"Au"``), sorted."""
    names = [p.name[: -len(".csv")] for p in _nk_dir().iterdir() if p.name.endswith(".csv")]
    return tuple(sorted(names))


def _check_name(name: str) -> None:
    if name not in materials():
        raise ValueError(f"unknown material {name!r}; valid names are: {', '.join(materials())}")


@functools.cache
def _read(name: str):
    """Parse ``<name>.csv`` once: (comment text, read-only float64 table with nm wavelengths)."""
    _check_name(name)
    text = (_nk_dir() / f"{name}.csv").read_text(encoding="utf-8")
    comments, rows = [], []
    header_seen = False
    for line in text.splitlines():
        line = line.strip()
        if not line:
            continue
        if line.startswith("#"):
            comments.append(line.lstrip("#").strip())
        elif not header_seen:
            header_seen = True  # the column names line "wavelength_um,n,k"
        else:
            rows.append([float(v) for v in line.split(",")])
    table = np.asarray(rows, dtype=np.float64)
    table[:, 0] *= 1000.0  # um -> nm
    if table.ndim != 2 or table.shape[1] != 3 or np.any(np.diff(table[:, 0]) <= 0):
        raise ValueError(f"malformed optical-constant table for {name!r}")
    table.setflags(write=False)
    return "\n".join(comments), table


def source(name: str) -> str:
    """The provenance text of a material's table (its CSV comment lines, ``#`` removed)."""
    return _read(name)[0]


def load_nk(name: str):
    """The tabulated optical constants of ``name``: ``(wavelength_nm, n, k)``, float64 arrays.

    Wavelengths are strictly increasing. Raises :class:`ValueError` for an unknown name (the
    message lists :func:`materials`).
    """
    table = _read(name)[1]
    return table[:, 0].copy(), table[:, 1].copy(), table[:, 2].copy()


def default_wavelengths() -> np.ndarray:
    """The default spectral grid: 380, 390, ..., 780 nm (41 wavelengths, float64).

    Chosen as the visible range commonly used for colorimetric integration, at 10 nm, a standard
    colorimetric sampling interval (ASTM E308 tabulates tristimulus weights at 10 nm). It is
    also about the spacing of the Johnson & Christy data in the visible (roughly 10-30 nm), so a
    finer grid would mostly add linearly interpolated points. :func:`spectrum_to_rgb` itself
    integrates on a 1 nm grid over 360-780 nm (the range of the CIE D65 table that overlaps
    the CIE 1931 tables), after interpolating the spectrum onto it.
    """
    return np.linspace(380.0, 780.0, 41)


def nk_at(name: str, wavelengths_nm):
    """``(n, k)`` of ``name`` linearly interpolated at ``wavelengths_nm`` (float64 NumPy arrays
    of the input's shape). A wavelength outside the tabulated range raises :class:`ValueError`."""
    wl, n, k = load_nk(name)
    x = np.asarray(wavelengths_nm, dtype=np.float64)
    if not np.all(np.isfinite(x)) or np.any(x < wl[0]) or np.any(x > wl[-1]):
        raise ValueError(
            f"wavelengths must lie in the tabulated range of {name!r}: "
            f"{wl[0]:g}-{wl[-1]:g} nm (got {np.min(x):g}-{np.max(x):g} nm)"
        )
    return np.interp(x, wl, n), np.interp(x, wl, k)


def spectral_reflectance(name: str, cos_theta=1.0, wavelengths_nm=None):
    """Unpolarised Fresnel reflectance of a smooth ``name`` surface at each wavelength (JAX).

    ``cos_theta`` of shape ``(...)`` gives a result of shape ``(..., n_wavelengths)``
    (wavelengths default to :func:`default_wavelengths`). Computed with
    :func:`brdf_fit.fresnel.conductor` in the floating dtype of ``cos_theta`` (the default float
    dtype for Python numbers and integers), so it is differentiable in ``cos_theta``.
    """
    if wavelengths_nm is None:
        wavelengths_nm = default_wavelengths()
    n, k = nk_at(name, np.ravel(np.asarray(wavelengths_nm, dtype=np.float64)))
    c = jnp.asarray(cos_theta)
    if not jnp.issubdtype(c.dtype, jnp.floating):
        c = c.astype(jnp.result_type(float))
    eta, k = jnp.asarray(n, dtype=c.dtype), jnp.asarray(k, dtype=c.dtype)
    return _conductor_jit(c[..., None], eta, k)


@functools.lru_cache(maxsize=1)
def _cie_tables():
    """CIE 1931 2 degree CMFs and D65 on the common 1 nm grid (no extrapolation needed)."""
    shape = colour.SpectralShape(_CIE_START_NM, _CIE_END_NM, _CIE_STEP_NM)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().trim(shape)
    illuminant = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    return shape, cmfs, illuminant


def _spectra_to_rgb_raw(values_on_grid: np.ndarray) -> np.ndarray:
    """(..., n_grid) reflectances on the CIE grid -> linear sRGB with the IEC 61966-2-1 matrix."""
    shape, cmfs, illuminant = _cie_tables()
    with colour.utilities.domain_range_scale("1"):
        # k=None: Y = 1 for the perfect reflector. Every spectral input is already on `shape`,
        # so colour-science does not need to align (and warn about) anything.
        XYZ = colour.sd_to_XYZ(values_on_grid, cmfs, illuminant, method="Integration", shape=shape)
        # The sRGB white point is D65, so no chromatic adaptation is wanted (illuminant=None).
        return colour.XYZ_to_RGB(XYZ, "sRGB", apply_cctf_encoding=False)


@functools.lru_cache(maxsize=1)
def _white_rgb() -> np.ndarray:
    shape = _cie_tables()[0]
    return _spectra_to_rgb_raw(np.ones(len(shape.wavelengths)))


def spectrum_to_rgb(values, wavelengths_nm) -> np.ndarray:
    """Linear sRGB (no transfer function) of a reflectance spectrum seen under D65.

    ``values`` has shape ``(..., n_wl)`` (leading batch axes allowed) sampled at the increasing
    ``wavelengths_nm`` of shape ``(n_wl,)``; the result has shape ``(..., 3)`` (NumPy float64).

    Method: the spectrum is linearly interpolated onto a 1 nm grid over 360-780 nm (held at its
    end values outside the sampled range: the constant extrapolation of CIE 15:2004 and
    CIE 167:2005 that colour-science also defaults to), integrated against the CIE 1931 2 degree
    CMFs weighted by D65 with colour-science (Y = 1 for a perfect reflector) and converted to
    linear sRGB with the IEC 61966-2-1 matrix. Because the IEC matrix is rounded and the
    tabulated D65 chromaticity differs from the rounded sRGB white point in the 4th decimal,
    that path maps the perfect reflector to 1 only within ~2e-4; the result is therefore
    white-balanced by dividing each channel by the RGB of the perfect reflector, so a constant
    spectrum ``c`` maps to ``(c, c, c)`` exactly (and grazing conductor reflectance, which
    tends to 1 at every wavelength, to white). Saturated colours may leave the sRGB gamut
    (a channel above 1 or below 0); no gamut mapping is applied.
    """
    v = np.asarray(values, dtype=np.float64)
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    if wl.ndim != 1 or v.ndim < 1 or v.shape[-1] != wl.shape[0]:
        raise ValueError(
            f"values of shape {v.shape} do not match wavelengths_nm of shape {wl.shape}"
        )
    if wl.shape[0] < 2 or np.any(np.diff(wl) <= 0):
        raise ValueError("wavelengths_nm must be strictly increasing with at least 2 samples")
    grid = _cie_tables()[0].wavelengths
    # Linear interpolation is linear in the values: build the (n_grid, n_wl) matrix once.
    interp = np.stack([np.interp(grid, wl, e) for e in np.eye(wl.shape[0])], axis=-1)
    on_grid = v @ interp.T
    return _spectra_to_rgb_raw(on_grid) / _white_rgb()


def reflectance_rgb(name: str, cos_theta=1.0) -> np.ndarray:
    """Linear sRGB of the conductor reflectance of ``name`` at ``cos_theta`` (shape ``(...)`` ->
    ``(..., 3)``): the spectral Fresnel reflectance first, then :func:`spectrum_to_rgb`."""
    wl = default_wavelengths()
    with _x64():
        refl = spectral_reflectance(name, np.asarray(cos_theta, dtype=np.float64), wl)
        refl = np.asarray(refl, dtype=np.float64)
    return spectrum_to_rgb(refl, wl)


def _x64():
    """Context enabling float64 in JAX locally (the fit must not depend on the global setting)."""
    enable = getattr(jax, "enable_x64", None)
    if enable is not None:
        return enable(True)
    from jax.experimental import enable_x64  # older JAX

    return enable_x64()


def _gulbrandsen_nk(r, g):
    """Gulbrandsen (2014) map from normal reflectivity ``r`` and edge tint ``g`` to ``(n, k)``
    (``F(1) = r`` exactly for every ``g``; ``g = 0`` is the dielectric, ``g = 1`` the most
    metallic end)."""
    sr = np.sqrt(r)
    n = g * (1.0 - r) / (1.0 + r) + (1.0 - g) * (1.0 + sr) / (1.0 - sr)
    k2 = (r * (n + 1.0) ** 2 - (n - 1.0) ** 2) / (1.0 - r)
    return n, np.sqrt(np.maximum(k2, 0.0))


@functools.lru_cache(maxsize=1)
def _fit_functions():
    """Jitted residual and Jacobian in log-parameters ``p = (log eta, log k)``."""

    def model(p, cos):
        return conductor(cos, jnp.exp(p[0]), jnp.exp(p[1]))

    return jax.jit(model), jax.jit(jax.jacfwd(model))


def _fit_channel(cos, target, weights, steps=100):
    """Weighted Levenberg-Marquardt fit of one channel; returns ``(eta, k)``."""
    model, jac = _fit_functions()
    sw = np.sqrt(weights)

    def residual(p):
        return sw * (np.asarray(model(p, cos)) - target)

    # Start: the best of Gulbrandsen's one-parameter family through F(1) = target(cos=1).
    lo, hi = np.log(_NK_MIN), np.log(_NK_MAX)
    r0 = float(np.clip(target[np.argmax(cos)], 1e-4, 0.9999))
    gs = np.linspace(0.0, 1.0, 41)
    starts = [np.clip(np.log(np.maximum(_gulbrandsen_nk(r0, g), _NK_MIN)), lo, hi) for g in gs]
    p = min(starts, key=lambda q: float(np.sum(residual(q) ** 2)))
    res = residual(p)
    cost, lam = float(res @ res), 1e-3
    for _ in range(steps):
        J = sw[:, None] * np.asarray(jac(p, cos))
        JtJ, Jtr = J.T @ J, J.T @ res
        step = np.linalg.solve(JtJ + lam * np.diag(np.diag(JtJ) + 1e-12), -Jtr)
        p_new = np.clip(p + step, lo, hi)  # projected step: stay inside the box
        res_new = residual(p_new)
        cost_new = float(res_new @ res_new)
        if cost_new < cost:
            done = cost - cost_new <= 1e-14 * cost or np.max(np.abs(p_new - p)) < 1e-12
            p, res, cost, lam = p_new, res_new, cost_new, max(lam / 3.0, 1e-12)
            if done:
                break
        else:
            lam *= 4.0
            if lam > 1e12:  # no descent left (converged, or pinned at the box)
                break
    return np.exp(p)


@functools.cache
def _rgb_nk_cached(name: str):
    _check_name(name)
    x, w = np.polynomial.legendre.leggauss(_FIT_NODES)
    cos, weights = 0.5 * (x + 1.0), 0.5 * w  # Gauss-Legendre on (0, 1)
    cos = np.concatenate([cos, [1.0]])  # include normal incidence so F(1) is matched tightly
    weights = np.concatenate([weights, [np.max(weights)]])
    target = reflectance_rgb(name, cos)
    dense = reflectance_rgb(name, np.linspace(0.0, 1.0, _CHECK_POINTS))
    out_of_gamut = dense.max(axis=0) > 1.0
    target = np.where(out_of_gamut, np.minimum(target, R_CLIP), target)
    eta, k = np.empty(3), np.empty(3)
    with _x64():
        cos64 = jnp.asarray(cos, dtype=jnp.float64)
        for ch in range(3):
            eta[ch], k[ch] = _fit_channel(cos64, target[:, ch], weights)
    eta.setflags(write=False)
    k.setflags(write=False)
    return eta, k


def rgb_nk(name: str):
    """Effective per-channel complex index ``(eta_rgb, k_rgb)`` of ``name`` (arrays of shape (3,)).

    ``conductor(cos, eta_rgb, k_rgb)`` reproduces ``reflectance_rgb(name, cos)`` channel by channel
    over the whole angular range (max abs error: :func:`rgb_nk_fit_error`).

    Method: for each channel independently, the RGB reflectance curve is sampled at 64
    Gauss-Legendre nodes in cos theta on (0, 1) plus cos = 1, and ``(log eta, log k)`` are fitted
    by weighted least squares (Gauss-Legendre weights, i.e. the L2 error over cos) with a small
    Levenberg-Marquardt loop in float64, the Jacobian of :func:`brdf_fit.fresnel.conductor` taken
    by JAX forward-mode differentiation. Log-parameters keep eta and k positive. The start is the
    best of 41 members of Gulbrandsen's (2014) family with the fitted channel's normal reflectance
    (edge tint g = 0, 0.025, ..., 1). Results are cached per material.

    Both parameters are kept in [1e-3, 100] (projected steps). A conductor reflects at most 1, so
    a channel whose linear-sRGB reflectance exceeds 1 anywhere (out of the sRGB gamut; gold's red
    channel, 1.037 at normal incidence) cannot be matched: its target is clipped to
    :data:`R_CLIP` = 0.995 before the fit (so gold's red is a real conductor, F(1) = 0.995 with
    finite eta and k, not the box corner F = 1 everywhere), and :func:`rgb_nk_fit_error` reports
    the difference to the unclipped curve (gold: 0.042).
    """
    eta, k = _rgb_nk_cached(name)
    return eta.copy(), k.copy()


@functools.cache
def _fit_error_cached(name: str) -> np.ndarray:
    eta, k = _rgb_nk_cached(name)
    cos = np.linspace(0.0, 1.0, _CHECK_POINTS)
    target = reflectance_rgb(name, cos)
    with _x64():
        fitted = np.asarray(
            _conductor_jit(jnp.asarray(cos)[:, None], jnp.asarray(eta), jnp.asarray(k)),
            dtype=np.float64,
        )
    err = np.max(np.abs(fitted - target), axis=0)
    err.setflags(write=False)
    return err


def rgb_nk_fit_error(name: str) -> np.ndarray:
    """Max abs difference over cos theta in [0, 1] (257 uniform samples, both ends included)
    between ``conductor(cos, *rgb_nk(name))`` and ``reflectance_rgb(name, cos)``, per channel."""
    return _fit_error_cached(name).copy()


def conductor_fresnel(name: str, mode: str = "rgb", wavelengths_nm=None) -> ConductorFresnel:
    """Exact conductor Fresnel of a tabulated metal (:func:`materials`).

    ``mode="rgb"``: effective linear-sRGB (eta, k) per channel (:func:`rgb_nk`);
    ``mode="spectral"``: eta and k interpolated at ``wavelengths_nm`` (default:
    :func:`default_wavelengths`), one channel per wavelength.
    """
    if mode == "rgb":
        eta, k = rgb_nk(name)
    elif mode == "spectral":
        if wavelengths_nm is None:
            wavelengths_nm = default_wavelengths()
        eta, k = nk_at(name, wavelengths_nm)
    else:
        raise ValueError(f"mode must be 'rgb' or 'spectral', got {mode!r}")
    return ConductorFresnel(eta=jnp.asarray(eta), k=jnp.asarray(k))
