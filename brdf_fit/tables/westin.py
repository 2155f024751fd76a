"""Westin, Arvo & Torrance (1992) tables: a virtual gonioreflectometer that ray traces a
micro-geometry of primitives (upright fibres over a floor, each with a registry BRDF) by Monte
Carlo through multiple bounces and projects the escaping rays onto a smooth basis, tabulated for
:class:`brdf_fit.models.westin.Westin`.

References
----------
- S. H. Westin, J. R. Arvo, K. E. Torrance, "Predicting reflectance functions from complex
  surfaces", SIGGRAPH 92, Computer Graphics 26(2):255-264, 1992: the BRDF of a surface is
  *computed* by shooting rays from each incident direction at a small piece of explicit
  micro-geometry whose primitives carry a finer-scale BRDF, following them through multiple
  bounces, and projecting the escaping rays' weights onto a basis of the outgoing direction
  (their basis: spherical harmonics, with the coefficient matrix symmetrised so that the result
  is reciprocal; their examples include cloth and velvet made of cylindrical fibres). The paper
  itself was not available here (docs/catalogue_numerical.md); what follows is derived and
  checked numerically, not transcribed.

The micro-geometry (:class:`MicroGeometry`)
-------------------------------------------
A floor ``z = 0`` with a local BRDF, under a layer ``0 < z < H`` of upright cylindrical fibres of
radius ``r = 1`` (the unit of length) with flat caps at ``z = H``, their axes placed at random
(a Poisson process of density ``n`` per unit area: the Boolean model of stochastic geometry,
overlaps allowed), each fibre with its own local BRDF (sides and caps). ``coverage`` is the
fraction of the top plane the caps cover, ``c = 1 - exp(-n pi r^2)``. ``coverage = 0`` is the
**flat** micro-geometry: the floor alone.

Why random and not periodic: for the Boolean model the distance a ray travels in the void before
it meets a fibre is exponential (the linear contact distribution of the Boolean model of discs:
``P(no fibre within horizontal distance s) = exp(-2 r n s)``, from any point of the void, in any
horizontal direction), and the point where it meets the fibre has an impact parameter ``b``
uniform on ``[-r, r]`` across the fibre's silhouette. So a ray is traced without cells or
intersection tests: its state is its height ``z``, direction and weight. The ensemble is
statistically isotropic about ``z`` and mirror symmetric, so the BRDF depends on
``(theta_i, theta_o, phi_d)`` only. **Approximation**: each flight draws a fresh free path
(annealed disorder), i.e. the correlation between the way in and the way out of a given
realisation is lost (a ray that retraces its path would find it empty: the hot-spot /
opposition effect near exact back-scatter is not reproduced). A convex fibre is never hit again
right after leaving it, which the fresh draw respects.

The tracer (:func:`trace`)
--------------------------
Per ray: the incident direction ``wi`` (toward the light) at azimuth 0, the ray travels along
``-wi`` from ``z = H``. At the top plane it hits a cap with probability ``c`` (normal ``+z``);
otherwise, and after every scattering event, it flies: path length to the floor (``dz < 0``) or
to the top (``dz > 0``) ``t_b``, path length to a fibre ``t_f = E / (2 r n |d_xy|)`` with
``E ~ Exp(1)``. ``t_f < t_b``: it hits a fibre side at ``z + t_f d_z`` with the horizontal normal
``-sqrt(1 - b^2) u + b u_perp`` (``u`` the ray's horizontal direction); otherwise it hits the
floor or escapes through the top. At a hit the local model's own importance sampler (registry
``sample``, in the local frame: normal ``n``, tangent the fibre axis) draws the new direction and
the weight is multiplied by ``f cos / pdf`` (``BRDFSample.weight``); a failed sample ends the path
(weight 0). Up to ``max_events`` flights; the weight of paths still in flight after that is
**truncated** (recorded per incident bin in the table's metadata).
Vectorised over rays (arrays, ``jax.lax.scan`` over events), ``jax.random`` keys
``fold_in(PRNGKey(seed), block)``, blocks of ``block`` rays with a progress bar on stderr.

The basis (:func:`estimate`): cosine-weighted bin-pair averages
--------------------------------------------------------------
Not spherical harmonics: a truncated SH expansion rings (negative values, which the checks would
reject) and needs high orders for the fibres' grazing lobes. Instead the bins
``B_k = [k, k + 1) pi / (2 n_theta)`` in ``theta`` and ``P_m = [m, m + 1) pi / n_phi`` in
``|phi_d|`` (``phi_d`` the angle between the horizontal projections of ``wi`` and ``wo``:
0 is back-scatter, ``pi`` the mirror side), and each table cell is the average

    F[k, l, m] = Int_{B_k} Int_{B_l x P_m} f(wi, wo) cos_i cos_o dwi dwo / (C_k C_lm),
    C_k = Int_{B_k} cos dw,

estimated without bias by drawing ``wi`` in ``B_k`` with density ``cos_i / C_k`` (``sin^2
theta_i`` uniform) and summing the weights of the rays that escape into ``B_l x P_m``, divided by
``N C_lm``. The target is **symmetric** under ``(k, l) -> (l, k)``: the local BRDFs are
reciprocal, and so is the random medium's scattering kernel, per unit path length
``n r Int f(-d, d') (n.(-d))_+ (n.d')_+ dalpha`` over the fibre's normals (its extinction
``2 r n |d_xy|`` is even in ``d``); the unsymmetrised estimate is reciprocal to its Monte Carlo
error (tested). So the table is symmetrised, ``(F[k, l] + F[l, k]) / 2``: **reciprocal by
construction**, the expectation unchanged and the noise reduced. The Monte Carlo standard error of
every cell comes from the second moment of the ray weights (each ray escapes into one bin at
most); symmetrised as ``sqrt(se[k, l]^2 + se[l, k]^2) / 2`` (independent runs, ``k != l``).
Values are non-negative (weights are), so no ringing. ``eval`` interpolates the cells
multilinearly at their centres (texel-centre axes, :class:`brdf_fit.core.table.Table`): a
smoothing of the BRDF at the bin width (5.6 degrees in theta and 11.25 in phi for the presets),
like any measured table; the flat-geometry test compares with the exact bin averages of the
local BRDF (:func:`bin_average`), so that it tests the tracer to the Monte Carlo error, not the
binning.

Measured (2-core CPU, float64; tests/models/test_westin.py holds the tolerances)
-------------------------------------------------------------------------------
* Flat micro-geometry (8 x 8 x 8 cells, 2^13 rays per incident bin), cell by cell against the
  exact bin averages of the local BRDF in units of the cell's standard error: Lambert
  (``rho = 0.7``) RMS 0.98, max 2.9, mean -0.06 (512 cells; albedo exactly ``rho``, 1e-12);
  GGX (``alpha = 0.3``, ``F0 = 1``) RMS 1.06 / 1.02, max 2.8 / 3.0 (two seeds). Negative
  controls: a 5% brighter Lambert gives mean score -0.77, a 10% wider GGX lobe RMS 1.7.
* Preset ``velvet``: 2^20 rays per incident bin (16.8 million), at most 16 flights each, 327 s on
  the shared 2-core CPU (load average 6-7); per-cell relative standard error median 1.5%, 90th
  percentile 2.9%, max 4.7% (all 4096 cells above 1% of the peak); albedo 0.282 (normal
  incidence) to 0.469 (grazing bin), its error <= 4.4e-4; truncated weight <= 2.5e-5. A fresh
  recomputation with 2^12 rays per bin and other seeds agrees within the combined errors (RMS
  score 0.94 / 1.05 over the 256 ``phi_d`` sums). Files: 77 kB ``.npz``, 3 kB ``.json``.
* The BRDF of the preset: dark at normal incidence (half the light reaches the floor between the
  fibres), back-scatter rising towards grazing (``F = 0.66`` at ``theta_i = theta_o = 87``
  degrees, ``phi_d = 0``, against 0.13 at the pole) and a forward peak from the fibres' glossy
  sides at grazing (3.0 at ``phi_d = pi``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import pathlib
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit import registry
from brdf_fit.core.table import Axis, Table
from brdf_fit.tables.export import write_table

__all__ = [
    "CELL_FLOOR",
    "Local",
    "MicroGeometry",
    "PRESETS",
    "bin_average",
    "build_table",
    "estimate",
    "stderr_progress",
    "trace",
    "write_preset",
]

#: relative floor (of the table's largest value) below which a cell is left out of the Monte
#: Carlo error summary: cells the rays almost never reach have a relative error that says
#: nothing about the table (their value is ~0 anyway)
CELL_FLOOR = 1e-2


@dataclasses.dataclass(frozen=True)
class Local:
    """A registry BRDF as the local reflectance of a primitive: an entry name and scalar
    parameter values (grey: the table is one channel; colour enters the model linearly)."""

    entry: str
    params: tuple[tuple[str, float], ...] = ()

    def build(self):
        return registry.get(self.entry).build(**{k: float(v) for k, v in self.params})

    def to_dict(self) -> dict:
        return {"entry": self.entry, "params": {k: float(v) for k, v in self.params}}


@dataclasses.dataclass(frozen=True)
class MicroGeometry:
    """A floor under a layer of random upright fibres (module docstring); lengths in fibre
    radii. ``coverage = 0``: the flat micro-geometry (the floor alone)."""

    name: str
    floor: Local
    fibre: Local | None = None
    #: layer thickness H (fibre length), in fibre radii
    height: float = 0.0
    #: fraction of the top plane covered by the caps, 1 - exp(-n pi r^2)
    coverage: float = 0.0
    #: flights per path (each ends in a scattering event or an escape); the weight still in
    #: flight after them is truncated and recorded
    max_events: int = 16
    n_theta: int = 16
    n_phi: int = 16
    #: rays per incident theta bin
    rays: int = 2**16
    seed: int = 1992
    #: rays per traced block (a multiple of n_theta)
    block: int = 2**14

    def __post_init__(self):
        if not 0.0 <= self.coverage < 1.0:
            raise ValueError(f"{self.name}: coverage must be in [0, 1), got {self.coverage}")
        if self.coverage > 0.0 and (self.fibre is None or self.height <= 0.0):
            raise ValueError(f"{self.name}: fibres need a local BRDF and a height > 0")
        if self.block % self.n_theta or (self.rays * self.n_theta) % self.block:
            raise ValueError(f"{self.name}: block must be a multiple of n_theta and divide "
                             "rays * n_theta")

    @property
    def flat(self) -> bool:
        return self.coverage == 0.0

    @property
    def density(self) -> float:
        """Fibres per unit area (``r = 1``): ``-log(1 - c) / pi``."""
        return -math.log1p(-self.coverage) / math.pi

    @property
    def sigma(self) -> float:
        """Fibres met per unit horizontal path length: ``2 r n``."""
        return 2.0 * self.density

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["floor"] = self.floor.to_dict()
        d["fibre"] = None if self.fibre is None else self.fibre.to_dict()
        d.update(density=self.density, mean_free_path=(1.0 / self.sigma if self.sigma else None))
        return d


#: the shipped presets. velvet: a dense pile (half the top covered by caps; horizontal mean free
#: path 2.27 radii) of shiny dielectric fibres 20 radii long (GGX plastic: diffuse 0.5, alpha 0.3,
#: F0 0.04) on a Lambertian floor of albedo 0.5: at normal incidence half the light reaches the
#: floor between the fibres (dark), near grazing the fibre sides catch it (the sheen of velvet)
PRESETS: dict[str, MicroGeometry] = {
    "velvet": MicroGeometry(
        "velvet", floor=Local("lambert", (("rho", 0.5),)),
        fibre=Local("ggx-plastic", (("rho_d", 0.5), ("alpha", 0.3), ("f0", 0.04))),
        height=20.0, coverage=0.5, rays=2**20, block=2**16),
}


# ----------------------------------------------------------------------------- tracing


def _world_from_fibre(lx, ly, lz, nx, ny):
    """Local fibre frame (x: the fibre axis ``+z``, z: the normal ``(nx, ny, 0)``, y = n x t =
    ``(ny, -nx, 0)``) to world."""
    return ly * ny + lz * nx, -ly * nx + lz * ny, lx


def _sample_in_frame(model, wo_local, key):
    k1, k2 = jax.random.split(key)
    uc = jax.random.uniform(k1, wo_local.shape[:-1], dtype=wo_local.dtype)
    u = jax.random.uniform(k2, wo_local.shape, dtype=wo_local.dtype)[..., :2]
    s = model.sample(wo_local, uc, u)
    return s.wi, s.weight


@functools.partial(jax.jit, static_argnames=("geo",))
def _trace_block(key, geo: MicroGeometry, floor_model, fibre_model):
    """One block: ``(S1, S2, trunc)`` with ``S1[k, l, m]`` the sum of escaping weights of the
    rays of incident bin ``k`` into outgoing bin ``(l, m)``, ``S2`` of their squares, ``trunc[k]``
    the weight still in flight after ``max_events``."""
    nt, nph, B = geo.n_theta, geo.n_phi, geo.block
    H, sigma, cov = float(geo.height), float(geo.sigma), float(geo.coverage)
    f64 = jnp.float64
    k_inc, k_cap, k_capdir, k_scan = jax.random.split(key, 4)
    kbin = jnp.arange(B, dtype=jnp.int32) % nt
    # wi with density cos / C_k inside bin k: sin^2 theta uniform on the bin
    dth = 0.5 * math.pi / nt
    kf = kbin.astype(f64)
    s2a, s2b = jnp.sin(kf * dth) ** 2, jnp.sin((kf + 1.0) * dth) ** 2
    s2 = s2a + (s2b - s2a) * jax.random.uniform(k_inc, (B,), dtype=f64)
    sin_i, cos_i = jnp.sqrt(s2), jnp.sqrt(1.0 - s2)
    dx, dy, dz = -sin_i, jnp.zeros(B, f64), -cos_i
    z = jnp.full(B, H, f64)
    w = jnp.ones(B, f64)
    if cov > 0.0:
        cap = jax.random.uniform(k_cap, (B,), dtype=f64) < cov
        wo_l = jnp.stack([sin_i, jnp.zeros_like(sin_i), cos_i], -1)
        wn, wt = _sample_in_frame(fibre_model, wo_l, k_capdir)
        dx, dy, dz = (jnp.where(cap, wn[:, 0], dx), jnp.where(cap, wn[:, 1], dy),
                      jnp.where(cap, wn[:, 2], dz))
        w = jnp.where(cap, wt, w)
    alive = w > 0
    nbins = nt * nt * nph

    def step(carry, key):
        z, dx, dy, dz, w, alive, S1, S2 = carry
        k_free, k_b, k_dir_f, k_dir_fl = jax.random.split(key, 4)
        sh2 = dx * dx + dy * dy
        moving = sh2 > 0
        sh = jnp.sqrt(jnp.where(moving, sh2, 1.0))
        up = dz > 0
        down = dz < 0
        dzs = jnp.where(up | down, dz, 1.0)
        t_b = jnp.where(up, (H - z) / dzs, jnp.where(down, z / -dzs, jnp.inf))
        t_b = jnp.maximum(t_b, 0.0)
        if sigma > 0.0:
            E = jax.random.exponential(k_free, (B,), dtype=f64)
            t_f = jnp.where(moving, E / (sigma * sh), jnp.inf)
        else:
            t_f = jnp.full(B, jnp.inf, f64)
        hit_f = alive & (t_f < t_b)
        esc = alive & ~hit_f & up
        hit_fl = alive & ~hit_f & down
        # escapes: bin and accumulate (each ray escapes at most once)
        th_o = jnp.arctan2(jnp.sqrt(sh2), jnp.where(up, dz, 1.0))
        ph_o = jnp.abs(jnp.arctan2(dy, dx))
        lb = jnp.clip(jnp.floor(th_o / dth).astype(jnp.int32), 0, nt - 1)
        mb = jnp.clip(jnp.floor(ph_o / (math.pi / nph)).astype(jnp.int32), 0, nph - 1)
        idx = (kbin * nt + lb) * nph + mb
        we = jnp.where(esc, w, 0.0)
        S1 = S1 + jax.ops.segment_sum(we, idx, num_segments=nbins)
        S2 = S2 + jax.ops.segment_sum(we * we, idx, num_segments=nbins)
        # fibre sides
        ux, uy = dx / sh, dy / sh
        b = jax.random.uniform(k_b, (B,), dtype=f64, minval=-1.0, maxval=1.0)
        c = jnp.sqrt(1.0 - b * b)
        nx, ny = -c * ux - b * uy, -c * uy + b * ux
        if sigma > 0.0:
            # wo (local) = -d in the fibre frame: (-d.t, -d.b, -d.n)
            wo_f = jnp.stack([-dz, -(dx * ny - dy * nx), -(dx * nx + dy * ny)], -1)
            wo_f = jnp.where(hit_f[:, None], wo_f, jnp.array([0.0, 0.0, 1.0]))
            wf, wtf = _sample_in_frame(fibre_model, wo_f, k_dir_f)
            fx, fy, fz = _world_from_fibre(wf[:, 0], wf[:, 1], wf[:, 2], nx, ny)
        else:
            fx = fy = fz = wtf = jnp.zeros(B, f64)
        wo_fl = jnp.stack([-dx, -dy, -dz], -1)
        wo_fl = jnp.where(hit_fl[:, None], wo_fl, jnp.array([0.0, 0.0, 1.0]))
        wfl, wtfl = _sample_in_frame(floor_model, wo_fl, k_dir_fl)
        z = jnp.where(hit_f, z + jnp.where(hit_f, t_f, 0.0) * dz, jnp.where(hit_fl, 0.0, z))
        z = jnp.clip(z, 0.0, H)
        dx = jnp.where(hit_f, fx, jnp.where(hit_fl, wfl[:, 0], dx))
        dy = jnp.where(hit_f, fy, jnp.where(hit_fl, wfl[:, 1], dy))
        dz = jnp.where(hit_f, fz, jnp.where(hit_fl, wfl[:, 2], dz))
        w = jnp.where(hit_f, w * wtf, jnp.where(hit_fl, w * wtfl, w))
        alive = (hit_f | hit_fl) & (w > 0)
        return (z, dx, dy, dz, w, alive, S1, S2), None

    zeros = jnp.zeros(nbins, f64)
    keys = jax.random.split(k_scan, geo.max_events)
    (z, dx, dy, dz, w, alive, S1, S2), _ = jax.lax.scan(
        step, (z, dx, dy, dz, w, alive, zeros, zeros), keys)
    trunc = jax.ops.segment_sum(jnp.where(alive, w, 0.0), kbin, num_segments=nt)
    return S1.reshape(nt, nt, nph), S2.reshape(nt, nt, nph), trunc


def stderr_progress(label: str) -> Callable[[int, int], None]:
    """A text progress bar on stderr: ``progress(done, total)``."""

    def progress(done: int, total: int) -> None:
        n = 30 * done // total
        sys.stderr.write(f"\r{label} [{'#' * n}{'.' * (30 - n)}] {done}/{total} blocks")
        if done == total:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return progress


def trace(geo: MicroGeometry, progress: Callable[[int, int], None] | None = None
          ) -> dict[str, np.ndarray]:
    """Trace ``geo.rays`` rays per incident bin; returns the raw sums ``S1``, ``S2`` (shape
    ``(n_theta, n_theta, n_phi)``), ``trunc`` (``n_theta``) and ``N`` (rays per bin), float64
    whatever the global setting. Deterministic for a given seed (block ``j`` uses
    ``fold_in(PRNGKey(seed), j)``)."""
    with jax.enable_x64(True):
        floor_model = geo.floor.build()
        fibre_model = geo.fibre.build() if geo.fibre is not None else floor_model
        n_blocks = geo.rays * geo.n_theta // geo.block
        base = jax.random.PRNGKey(geo.seed)
        S1 = S2 = trunc = None
        for j in range(n_blocks):
            a, b, c = _trace_block(jax.random.fold_in(base, j), geo, floor_model, fibre_model)
            S1, S2, trunc = (a, b, c) if S1 is None else (S1 + a, S2 + b, trunc + c)
            if progress is not None:
                progress(j + 1, n_blocks)
        return {"S1": np.asarray(S1), "S2": np.asarray(S2), "trunc": np.asarray(trunc),
                "N": geo.rays}


def _cell_cosine_measure(n_theta: int, n_phi: int) -> np.ndarray:
    """``C_lm = Int_{B_l x P_m} cos dw`` over both signs of ``phi``: ``(2 pi / n_phi)
    (sin^2 b - sin^2 a) / 2``, shape ``(n_theta, n_phi)``."""
    e = np.linspace(0.0, 0.5 * np.pi, n_theta + 1)
    ds2 = np.diff(np.sin(e) ** 2)
    return np.broadcast_to((np.pi / n_phi) * ds2[:, None], (n_theta, n_phi))


def estimate(raw: dict, symmetrise: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``(F, se)``: the cells ``F[k, l, m]`` (module docstring) and their Monte Carlo standard
    errors from the traced sums; ``symmetrise``: ``(F + F^T) / 2`` in ``(k, l)``."""
    S1, S2, N = raw["S1"], raw["S2"], raw["N"]
    nt, _, nph = S1.shape
    C = _cell_cosine_measure(nt, nph)[None]
    F = S1 / (N * C)
    var = np.maximum(S2 / (N * C * C) - F * F, 0.0)
    se = np.sqrt(var / max(N - 1, 1))
    if symmetrise:
        Ft, set_ = np.swapaxes(F, 0, 1), np.swapaxes(se, 0, 1)
        diag = np.eye(nt, dtype=bool)[:, :, None]
        F = np.where(diag, F, 0.5 * (F + Ft))
        se = np.where(diag, se, 0.5 * np.sqrt(se * se + set_ * set_))
    return F, se


def bin_average(model, n_theta: int, n_phi: int, nodes: int = 6) -> np.ndarray:
    """The exact target of :func:`estimate` for a model ``f`` (e.g. the local BRDF of the flat
    micro-geometry): ``Int Int f cos_i cos_o / (C_k C_lm)`` over each bin pair, by Gauss-Legendre
    with ``nodes`` nodes per bin in ``sin^2 theta`` (the cosine-weighted measure: ``cos sin
    dtheta = d(sin^2)/2``) and in ``phi``, ``wi`` at azimuth 0 (isotropic ``f``)."""
    x, wq = np.polynomial.legendre.leggauss(nodes)
    x, wq = 0.5 * (x + 1.0), 0.5 * wq
    e = np.linspace(0.0, 0.5 * np.pi, n_theta + 1)
    s2 = np.sin(e) ** 2
    u = (s2[:-1, None] + np.diff(s2)[:, None] * x[None]).ravel()  # (n_theta * nodes)
    ph = ((np.arange(n_phi)[:, None] + x[None]) * (np.pi / n_phi)).ravel()
    st, ct = np.sqrt(u), np.sqrt(1.0 - u)
    wi = np.stack([st, 0 * st, ct], -1)[:, None, None, :]
    wo = np.stack([st[:, None] * np.cos(ph)[None], st[:, None] * np.sin(ph)[None],
                   np.broadcast_to(ct[:, None], (u.size, ph.size))], -1)[None]
    with jax.enable_x64(True):
        f = np.asarray(model.eval(jnp.asarray(wi), jnp.asarray(wo)))
    W = wq
    f = f.reshape(n_theta, nodes, n_theta, nodes, n_phi, nodes)
    return np.einsum("a,b,c,kalbmc->klm", W, W, W, f)


def build_table(geo: MicroGeometry, progress: Callable[[int, int], None] | None = None
                ) -> Table:
    """Trace ``geo`` and tabulate: axes ``theta_i``, ``theta_o`` (texel centres on ``[0,
    pi/2]``), ``phi_d`` (texel centres on ``[0, pi]``); channels ``f`` (1/sr) and ``se`` (its
    Monte Carlo standard error); metadata: the geometry, seconds, the error summary, the albedo
    per incident bin with its error, the truncated weight."""
    t0 = time.perf_counter()
    raw = trace(geo, progress)
    seconds = time.perf_counter() - t0
    F, se = estimate(raw)
    N = raw["N"]
    # albedo per incident bin: total escaping weight / N (its error from the same sums)
    tot = raw["S1"].sum(axis=(1, 2)) / N
    tot2 = raw["S2"].sum(axis=(1, 2)) / N
    alb_se = np.sqrt(np.maximum(tot2 - tot * tot, 0.0) / (N - 1))
    big = F > CELL_FLOOR * F.max()
    rel = se[big] / F[big]
    meta = {
        "model": "westin",
        "geometry": geo.to_dict(),
        "seconds": round(seconds, 2),
        "rays_total": int(N * geo.n_theta),
        "mc_error": {"cells_over_floor": int(big.sum()), "cell_floor": CELL_FLOOR,
                     "rel_se_median": float(np.median(rel)), "rel_se_p90":
                     float(np.quantile(rel, 0.9)), "rel_se_max": float(rel.max()),
                     "abs_se_max": float(se.max())},
        "albedo": tot.tolist(),
        "albedo_se": alb_se.tolist(),
        "truncated": (raw["trunc"] / N).tolist(),
        "basis": "cosine-weighted bin-pair averages at texel centres, symmetrised in (theta_i,"
                 " theta_o)",
    }
    axes = (Axis("theta_i", 0.0, 0.5 * math.pi, geo.n_theta),
            Axis("theta_o", 0.0, 0.5 * math.pi, geo.n_theta),
            Axis("phi_d", 0.0, math.pi, geo.n_phi))
    return Table(np.stack([F, se], -1), axes, ("f", "se"), meta)


def write_preset(name: str, directory, progress=None) -> list:
    """Trace the preset and write ``westin_<name>.npz`` (+ ``.json``) into ``directory`` (the
    package ships ``brdf_fit/resources/tables``). Command line::

        python -m brdf_fit.tables.westin velvet brdf_fit/resources/tables
    """
    table = build_table(PRESETS[name], progress=progress)
    cmd = f"python -m brdf_fit.tables.westin {name} <directory>"
    table = table.with_meta(command=cmd)
    return write_table(table, pathlib.Path(directory) / f"westin_{name}.npz")


if __name__ == "__main__":  # pragma: no cover
    preset, out = sys.argv[1], sys.argv[2]
    print(write_preset(preset, out, progress=stderr_progress(f"westin {preset}")))
