"""Evaluation throughput of ``ggx-conductor`` and ``lambert`` under ``jax.jit`` (float32),
against a vectorised NumPy float32 implementation of exactly the same formulas, in one run.

    python benchmarks/bench_eval.py [--sizes 1e3 1e4 1e5 1e6] [--repeats 7] [--out DIR]

Implementations timed per batch size N (all float32, x64 left disabled):

``jax``          ``jax.jit(lambda m, wi, wo: m.eval(wi, wo))`` on the registry model cast with
                 ``brdf_fit.astype(model, jnp.float32)`` (the model is a jit argument, as when
                 fitting).
``numpy``        :class:`NumpyGGXConductor` / :class:`NumpyLambert` below (the baseline).
``numpy-alloc``  (GGX only) the same NumPy arithmetic as plain expressions that allocate their
                 temporaries on every call (:meth:`NumpyGGXConductor.eval_alloc`).
``jax-unpacked`` (GGX only) the NumPy formulas transcribed to ``jnp`` on unpacked components.
``jax-normsum``  (GGX only) the same formulas written ``jnp.linalg.norm(.., keepdims=True)`` /
                 ``jnp.sum(a * b, -1)`` style, to test the DESIGN note "component-unpacked kernels
                 are ~4x faster than norm/sum-style ones".
``roof-1d``      (GGX only, a roofline, not an evaluation) ``jax.jit(lambda x: x * 2.0)`` on a flat
                 float32 array of 4.5 N elements: 18 bytes read and 18 written per pair, the 36
                 bytes per evaluation of the (N, 3) kernel (24 read, 12 written), as one
                 contiguous stream: the memory-bandwidth bound of the machine through XLA.
``jax-separable`` (GGX only) the public API's ``MicrofacetBRDF(GGX, SmithSeparable,
                 ConductorFresnel)``: the function Mitsuba's ``roughconductor`` computes (the
                 registry's ``ggx-conductor`` has the height-correlated Smith G).
``mitsuba-llvm`` (GGX only, when Mitsuba 3 and an LLVM it can use are there) Mitsuba 3's
                 ``roughconductor`` (``distribution`` ggx, the same alpha and RGB eta, k) through
                 ``BSDF.eval`` in the ``llvm_ad_rgb`` variant, on resident inputs made opaque
                 (``dr.make_opaque``), every call traced and evaluated (``dr.eval``,
                 ``dr.sync_thread``; the compiled kernel comes from Dr.Jit's cache after the
                 first call). It returns ``f cos(theta)`` of its ``wo`` (our ``wi``): divided
                 by ``wi.z`` for the check, which is against ``jax-separable`` (an independent
                 implementation of the same formulas, <= 1e-4). Mitsuba's LLVM backend needs a
                 libLLVM it can load (version 19 works, 15 and 16 abort on ``fmaximum``):
                 Debian's package unpacked anywhere is enough,
                 ``apt-get download libllvm19 && dpkg-deb -x libllvm19_*.deb /tmp/llvm19``, then
                 ``--libllvm /tmp/llvm19/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1`` (or
                 ``DRJIT_LIBLLVM_PATH``). Without them the rows are left out and said so.
``roof-n3``      (GGX only, a roofline) ``jax.jit(lambda a, b: a + b)`` on the (N, 3) inputs: the
                 same 36 bytes per pair in the kernel's layout. XLA CPU (jaxlib 0.10) emits a
                 lone (N, 3) elementwise op with its tiled emitter, one 3-float row per
                 iteration through a stack temporary (no vectorisation across rows): several
                 times slower than ``roof-1d`` (a layout cost, not a bandwidth one; the fused
                 model kernels go through the loop emitter and are vectorised 8 rows at a time).

Threads: XLA CPU splits every loop fusion of these kernels into as many partitions as there are
cores (``backend_config={"outer_dimension_partitions":["2"]}`` in the compiled HLO on a 2-core
machine), so the ``jax*`` rows use all cores; the NumPy rows use one. Under load from other
processes the multi-threaded rows lose more than the single-threaded ones.

Before timing, every implementation is checked against ``model.eval`` on the benchmark inputs
(relative error <= 1e-4 on every output, identical zeros); the script exits non-zero otherwise.

Timing: one warm-up call (compiles the jitted functions), then an inner loop count is calibrated
so that one sample lasts at least ``--min-time`` seconds; ``--repeats`` samples are taken per
implementation, interleaved across implementations (so drift of a shared machine hits them all
alike). Every call is followed by ``block_until_ready()`` (JAX) and each sample is timed with
``time.perf_counter``. Reported: median and best seconds per call, evaluations per second, and
the ratio jax/numpy of throughputs (> 1: JAX faster). The load average before and after the
run is recorded: the numbers are only meaningful on an otherwise idle machine.

Results go to ``<out>/eval.md`` and ``<out>/eval.json`` with the command line and machine info.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import shlex
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import brdf_fit
from brdf_fit import registry
from brdf_fit.core.fresnel import ConductorFresnel, conductor
from brdf_fit.core.microfacet import GGX, SmithSeparable
from brdf_fit.models import MicrofacetBRDF

ALPHA = 0.3
RTOL = 1e-4
SEED = 20240607
F32 = np.float32


# ----------------------------------------------------------------------------- inputs


def hemisphere_directions(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` float32 unit directions uniform on the upper hemisphere (z = normal), shape (n, 3)."""
    u1 = rng.random(n)
    u2 = rng.random(n)
    z = u1
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * u2
    w = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
    w /= np.linalg.norm(w, axis=-1, keepdims=True)
    return w.astype(F32)


def edge_directions(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Full-sphere pairs (about 3/4 of them have a direction below the horizon) plus degenerate
    ones: opposite horizon directions (h = 0), exact grazing, normal incidence, mirror pairs."""
    wi = rng.normal(size=(n, 3))
    wo = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    special_i = [(1, 0, 0), (0, 1, 0), (1, 0, 0), (0, 0, 1), (0, 0, 1), (0.6, 0, 0.8)]
    special_o = [(-1, 0, 0), (0, -1, 0), (0, 0, 1), (0, 0, 1), (0.6, 0, 0.8), (-0.6, 0, 0.8)]
    wi = np.concatenate([wi, special_i])
    wo = np.concatenate([wo, special_o])
    return wi.astype(F32), wo.astype(F32)


# ----------------------------------------------------------------------------- NumPy baseline


class NumpyGGXConductor:
    """``F(wo.h) D(h) V(wi, wo)`` in vectorised NumPy float32, the formulas of brdf_fit:

    - ``h = normalize(wi + wo)``, valid where ``iz > 0``, ``oz > 0`` and ``|wi + wo|^2 > 1e-24``;
    - GGX ``D = 1/(pi ax ay (hx^2/ax^2 + hy^2/ay^2 + hz^2)^2)``;
    - height-correlated Smith, division-free:
      ``V = 0.5/(co sqrt(ax^2 ix^2 + ay^2 iy^2 + ci^2) + ci sqrt(ax^2 ox^2 + ay^2 oy^2 + co^2))``;
    - exact conductor Fresnel in the real-arithmetic form of ``brdf_fit.core.fresnel.conductor``
      (both branches for ``a^2``, selected on the sign of ``t0``).

    Layout choices that matter for NumPy (measured, see benchmarks/README.md): directions are
    transposed once to contiguous (3, N) components (ops on strided (N, 3) columns are ~3x
    slower); the per-channel Fresnel runs channels-first, (3, 1) constants against (N,) cosines,
    because a (N, 1) x (3,) broadcast runs NumPy inner loops of length 3 (~30x slower); the
    (N, 3) result is written one channel column at a time, for the same reason. Per-channel
    constants are precomputed once. Invalid lanes are computed without guards (under
    ``np.errstate``) and masked at the end.

    ``__call__`` works in a per-N workspace of preallocated buffers with ``out=`` everywhere (only
    the returned array is allocated per call); :meth:`eval_alloc` is the same arithmetic written
    as plain expressions that allocate their temporaries on every call.
    """

    def __init__(self, alpha_x, alpha_y, eta, k):
        ax = F32(alpha_x)
        ay = F32(alpha_y)
        self.ax2, self.ay2 = ax * ax, ay * ay
        self.inv_ax2, self.inv_ay2 = F32(1.0) / self.ax2, F32(1.0) / self.ay2
        self.half_d_norm = F32(0.5) / (F32(np.pi) * ax * ay)  # 0.5 of V times 1/(pi ax ay) of D
        eta = np.asarray(eta, dtype=F32)[:, None]  # (channels, 1)
        k = np.asarray(k, dtype=F32)[:, None]
        eta2 = eta * eta
        ek2 = eta2 * k * k
        self.two_ek2 = F32(2.0) * ek2
        self.four_ek2 = F32(4.0) * ek2
        self.eta2_m_k2_m1 = eta2 - k * k - F32(1.0)  # t0 = eta^2 - k^2 - (1 - c^2)
        self.channels = eta.shape[0]
        self._ws: dict[int, dict[str, np.ndarray]] = {}

    # -- plain expressions (temporaries allocated per call)

    def eval_alloc(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            ix, iy, iz = np.ascontiguousarray(wi.T)
            ox, oy, oz = np.ascontiguousarray(wo.T)
            hx = ix + ox
            hy = iy + oy
            hz = iz + oz
            l2 = hx * hx + hy * hy + hz * hz
            valid = (iz > 0) & (oz > 0) & (l2 > F32(1e-24))
            inv_l = F32(1.0) / np.sqrt(l2)
            hx *= inv_l
            hy *= inv_l
            hz *= inv_l
            d = ox * hx + oy * hy + oz * hz  # wo.h
            s = hx * hx * self.inv_ax2 + hy * hy * self.inv_ay2 + hz * hz  # GGX D denominator
            p_i = np.sqrt(self.ax2 * (ix * ix) + self.ay2 * (iy * iy) + iz * iz)  # Smith P(wi)
            p_o = np.sqrt(self.ax2 * (ox * ox) + self.ay2 * (oy * oy) + oz * oz)
            dv = self.half_d_norm / (s * s * (oz * p_i + iz * p_o))
            dv = np.where(valid, dv, F32(0.0))
            d = np.where(valid, d, F32(1.0))  # no NaN from h = 0 into F (F * 0 must be 0)
            c = np.minimum(np.maximum(d, F32(0.0)), F32(1.0))  # (N,)
            c2 = c * c
            s2 = F32(1.0) - c2
            t0 = self.eta2_m_k2_m1 + c2  # (3, N)
            a2b2 = np.sqrt(t0 * t0 + self.four_ek2)
            a2 = np.where(t0 >= 0, F32(0.5) * (a2b2 + t0), self.two_ek2 / (a2b2 - t0))
            a = np.sqrt(np.maximum(a2, F32(0.0)))
            t1 = a2b2 + c2
            t2 = F32(2.0) * a * c
            rs = (t1 - t2) / (t1 + t2)
            t3 = a2b2 * c2 + s2 * s2
            t4 = t2 * s2
            rp = rs * ((t3 - t4) / (t3 + t4))
            f = np.where(t1 + t2 > 0, F32(0.5) * (rs + rp), F32(1.0))
            out = np.empty((wi.shape[0], self.channels), dtype=F32)
            for ch in range(self.channels):
                np.multiply(f[ch], dv, out=out[:, ch])
            return out

    # -- workspace version (the baseline)

    def _workspace(self, n: int) -> dict[str, np.ndarray]:
        ws = self._ws.get(n)
        if ws is None:
            self._ws.clear()  # keep one size only
            nc = self.channels
            ws = {name: np.empty((3, n), F32) for name in ("wi", "wo", "h")}
            ws.update({name: np.empty(n, F32) for name in ("t", "l2", "d", "s", "pi", "po", "dv",
                                                            "c2", "s2", "s2sq")})
            ws.update({name: np.empty((nc, n), F32) for name in ("t0", "a2b2", "a2", "u", "t1",
                                                                  "rs", "den", "t3", "t4")})
            ws.update({name: np.empty(n, bool) for name in ("valid", "b")})
            ws["pos"] = np.empty((nc, n), bool)
            self._ws[n] = ws
        return ws

    def _p(self, x, y, z, out, t):
        """Smith ``P = sqrt(ax^2 x^2 + ay^2 y^2 + z^2)`` into ``out``."""
        np.multiply(x, x, out=out)
        out *= self.ax2
        np.multiply(y, y, out=t)
        t *= self.ay2
        out += t
        np.multiply(z, z, out=t)
        out += t
        np.sqrt(out, out=out)

    def __call__(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        n = wi.shape[0]
        w = self._workspace(n)
        t = w["t"]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            np.copyto(w["wi"], wi.T)
            np.copyto(w["wo"], wo.T)
            ix, iy, iz = w["wi"]
            ox, oy, oz = w["wo"]
            np.add(w["wi"], w["wo"], out=w["h"])
            hx, hy, hz = w["h"]
            l2 = w["l2"]
            np.multiply(hx, hx, out=l2)
            np.multiply(hy, hy, out=t)
            l2 += t
            np.multiply(hz, hz, out=t)
            l2 += t
            valid, b = w["valid"], w["b"]
            np.greater(iz, 0, out=valid)
            np.greater(oz, 0, out=b)
            valid &= b
            np.greater(l2, F32(1e-24), out=b)
            valid &= b
            np.sqrt(l2, out=l2)
            np.divide(F32(1.0), l2, out=l2)  # 1/|h|
            w["h"] *= l2
            d = w["d"]  # wo.h
            np.multiply(ox, hx, out=d)
            np.multiply(oy, hy, out=t)
            d += t
            np.multiply(oz, hz, out=t)
            d += t
            s = w["s"]  # GGX D denominator, squared
            np.multiply(hx, hx, out=s)
            s *= self.inv_ax2
            np.multiply(hy, hy, out=t)
            t *= self.inv_ay2
            s += t
            np.multiply(hz, hz, out=t)
            s += t
            s *= s
            p_i, p_o, dv = w["pi"], w["po"], w["dv"]
            self._p(ix, iy, iz, p_i, t)
            self._p(ox, oy, oz, p_o, t)
            p_i *= oz
            p_o *= iz
            p_i += p_o
            p_i *= s
            np.divide(self.half_d_norm, p_i, out=dv)  # D V
            np.logical_not(valid, out=b)
            np.copyto(dv, F32(0.0), where=b)
            np.copyto(d, F32(1.0), where=b)  # no NaN from h = 0 into F (F * 0 must be 0)
            # exact conductor Fresnel, channels-first (3, N)
            c = d
            np.maximum(c, F32(0.0), out=c)
            np.minimum(c, F32(1.0), out=c)
            c2, s2 = w["c2"], w["s2"]
            np.multiply(c, c, out=c2)
            np.subtract(F32(1.0), c2, out=s2)
            t0, a2b2, a2, u = w["t0"], w["a2b2"], w["a2"], w["u"]
            np.add(self.eta2_m_k2_m1, c2, out=t0)
            np.multiply(t0, t0, out=a2b2)
            a2b2 += self.four_ek2
            np.sqrt(a2b2, out=a2b2)
            np.add(a2b2, t0, out=a2)
            a2 *= F32(0.5)  # a^2 where t0 >= 0
            np.subtract(a2b2, t0, out=u)
            np.divide(self.two_ek2, u, out=u)  # a^2 where t0 < 0
            pos = w["pos"]
            np.greater_equal(t0, 0, out=pos)
            np.copyto(u, a2, where=pos)
            np.maximum(u, F32(0.0), out=u)
            np.sqrt(u, out=u)  # a
            t1, rs, den, t3, t4 = w["t1"], w["rs"], w["den"], w["t3"], w["t4"]
            np.add(a2b2, c2, out=t1)
            u *= c
            u *= F32(2.0)  # t2 = 2 a c
            t2 = u
            np.subtract(t1, t2, out=rs)
            np.add(t1, t2, out=den)
            rs /= den  # Rs
            np.multiply(a2b2, c2, out=t3)
            s2sq = w["s2sq"]
            np.multiply(s2, s2, out=s2sq)
            t3 += s2sq
            np.multiply(t2, s2, out=t4)
            rp = a2b2  # a2b2 is no longer needed
            np.subtract(t3, t4, out=rp)
            t3 += t4
            rp /= t3
            rp *= rs  # Rp
            rs += rp
            rs *= F32(0.5)  # F
            np.greater(den, 0, out=pos)
            np.logical_not(pos, out=pos)
            np.copyto(rs, F32(1.0), where=pos)
            out = np.empty((n, self.channels), dtype=F32)
            for ch in range(self.channels):
                np.multiply(rs[ch], dv, out=out[:, ch])
            return out


class NumpyLambert:
    """``rho/pi`` where ``iz > 0`` and ``oz > 0``, else 0; float32 (N, 3), written one channel
    column at a time (a (N, 1) x (3,) ``np.where`` broadcast is ~4x slower)."""

    def __init__(self, rho):
        self.rho_pi = (np.asarray(rho, dtype=F32) / F32(np.pi)).astype(F32)

    def __call__(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        ok = wi[:, 2] > 0
        ok &= wo[:, 2] > 0
        okf = ok.astype(F32)
        out = np.empty((wi.shape[0], self.rho_pi.shape[0]), dtype=F32)
        for ch in range(self.rho_pi.shape[0]):
            np.multiply(okf, self.rho_pi[ch], out=out[:, ch])
        return out


# ----------------------------------------------------------------------------- JAX variants


def _ggx_dv(ax, ay, s, p_i, p_o, ci, co):
    return 0.5 / (math.pi * ax * ay * s * s * (co * p_i + ci * p_o))


@jax.jit
def jax_ggx_unpacked(params, wi, wo):
    """The NumPy formulas in ``jnp`` on components (no guards; masked at the end)."""
    ax, eta, k = params
    ay = ax
    ix, iy, iz = wi[:, 0], wi[:, 1], wi[:, 2]
    ox, oy, oz = wo[:, 0], wo[:, 1], wo[:, 2]
    hx, hy, hz = ix + ox, iy + oy, iz + oz
    l2 = hx * hx + hy * hy + hz * hz
    valid = (iz > 0) & (oz > 0) & (l2 > 1e-24)
    inv_l = 1.0 / jnp.sqrt(l2)
    hx, hy, hz = hx * inv_l, hy * inv_l, hz * inv_l
    d = ox * hx + oy * hy + oz * hz
    s = (hx / ax) ** 2 + (hy / ay) ** 2 + hz * hz
    p_i = jnp.sqrt((ax * ix) ** 2 + (ay * iy) ** 2 + iz * iz)
    p_o = jnp.sqrt((ax * ox) ** 2 + (ay * oy) ** 2 + oz * oz)
    dv = _ggx_dv(ax, ay, s, p_i, p_o, iz, oz)
    f = conductor(d[:, None], eta, k)
    return jnp.where(valid[:, None], f * dv[:, None], 0.0)


@jax.jit
def jax_ggx_normsum(params, wi, wo):
    """The same formulas written with ``jnp.linalg.norm(.., keepdims=True)`` and
    ``jnp.sum(a * b, -1)`` on (N, 3) vectors (no guards; masked at the end)."""
    ax, eta, k = params
    ay = ax
    one = jnp.ones_like(ax)
    a2 = jnp.stack([ax * ax, ay * ay, one])  # (3,) stretch of P
    inv_a2 = jnp.stack([1.0 / (ax * ax), 1.0 / (ay * ay), one])  # (3,) stretch of D
    h = wi + wo
    hl = jnp.linalg.norm(h, axis=-1, keepdims=True)
    ci = wi[:, 2:3]
    co = wo[:, 2:3]
    valid = (ci > 0) & (co > 0) & (hl > 1e-12)
    h = h / hl
    d = jnp.sum(wo * h, -1, keepdims=True)
    s = jnp.sum(h * h * inv_a2, -1, keepdims=True)
    p_i = jnp.sqrt(jnp.sum(wi * wi * a2, -1, keepdims=True))
    p_o = jnp.sqrt(jnp.sum(wo * wo * a2, -1, keepdims=True))
    dv = _ggx_dv(ax, ay, s, p_i, p_o, ci, co)
    f = conductor(d, eta, k)
    return jnp.where(valid, f * dv, 0.0)


@jax.jit
def jax_model_eval(model, wi, wo):
    return model.eval(wi, wo)


@jax.jit
def jax_roof_1d(x):
    """Roofline: one read and one write of ``x`` (float32), nothing else."""
    return x * 2.0


@jax.jit
def jax_roof_n3(a, b):
    """Roofline in the (N, 3) layout: reads both inputs, writes one (N, 3) array."""
    return a + b


# ----------------------------------------------------------------------------- Mitsuba 3

#: Mitsuba 3 in its ``llvm_ad_rgb`` variant, once loaded by :func:`load_mitsuba`; ``why``: the
#: reason it is not there
MITSUBA: dict = {"mi": None, "dr": None, "why": "not tried", "version": None, "libllvm": None}


#: A child process that evaluates the benchmark's kernel in Mitsuba's LLVM variant on a few
#: pairs: Dr.Jit with an LLVM it cannot use aborts the process (LLVM 15 and 16 on ``fmaximum``),
#: so the benchmark tries it in a child first
_PROBE = """
import mitsuba as mi, drjit as dr
mi.set_variant("llvm_ad_rgb")
b = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 0.3,
                  "eta": {"type": "rgb", "value": [0.2, 0.4, 1.4]},
                  "k": {"type": "rgb", "value": [3.5, 2.4, 1.8]}})
si = dr.zeros(mi.SurfaceInteraction3f, 16)
si.wi = dr.normalize(mi.Vector3f(0.3, 0.1, 0.9))
si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
v = b.eval(mi.BSDFContext(), si, dr.normalize(mi.Vector3f(-0.2, 0.3, 0.8)))
dr.eval(v)
print("ok", float(v[0][0]))
"""


def load_mitsuba(libllvm: str | None) -> None:
    """Import Mitsuba 3 and select ``llvm_ad_rgb`` (``libllvm``: the libLLVM to use, else
    ``DRJIT_LIBLLVM_PATH`` or Dr.Jit's own search), after a child process has evaluated the
    kernel with it (:data:`_PROBE`); on failure record why."""
    import subprocess

    if libllvm:
        os.environ["DRJIT_LIBLLVM_PATH"] = libllvm
    try:
        child = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                               timeout=300)
    except (OSError, subprocess.TimeoutExpired) as e:
        MITSUBA["why"] = f"probe failed: {e}"
        return
    if child.returncode != 0 or not child.stdout.startswith("ok"):
        last = (child.stderr.strip().splitlines() or [f"exit status {child.returncode}"])[-1]
        MITSUBA["why"] = (f"Mitsuba's llvm variant did not run here ({last[:160]}); give a "
                          "libLLVM 19 with --libllvm (see the module docstring)")
        return
    try:
        import drjit as dr
        import mitsuba as mi

        mi.set_variant("llvm_ad_rgb")
        x = dr.arange(mi.Float, 4)
        dr.eval(x * x)
    except Exception as e:  # ImportError, or the LLVM backend failing to start
        MITSUBA["why"] = f"{type(e).__name__}: {e}".splitlines()[0][:200]
        return
    MITSUBA.update(mi=mi, dr=dr, why=None, version=mi.__version__,
                   libllvm=os.environ.get("DRJIT_LIBLLVM_PATH"))


class MitsubaRoughConductor:
    """Mitsuba 3's ``roughconductor`` (GGX, separable Smith G, exact conductor Fresnel) at
    ``(wi, wo)`` pairs held as resident Dr.Jit arrays; a call traces ``BSDF.eval`` and
    evaluates it (the kernel compiled once, then taken from Dr.Jit's cache) and waits for it.
    :meth:`values` converts the result to our convention: ``f`` (N, 3), float32."""

    def __init__(self, alpha, eta, k, wi, wo):
        mi, dr = MITSUBA["mi"], MITSUBA["dr"]
        self.dr = dr
        self.bsdf = mi.load_dict({
            "type": "roughconductor", "distribution": "ggx", "alpha": float(alpha),
            "eta": {"type": "rgb", "value": [float(x) for x in eta]},
            "k": {"type": "rgb", "value": [float(x) for x in k]}})
        self.ctx = mi.BSDFContext()
        n = wi.shape[0]
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2])  # Mitsuba's wi: toward the viewer
        si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        self.si = si
        self.wl = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2])  # its wo: toward the light
        dr.make_opaque(self.si, self.wl)
        self.cos_i = wi[:, 2].astype(np.float64)

    def _eval(self):
        v = self.bsdf.eval(self.ctx, self.si, self.wl)
        self.dr.eval(v)
        self.dr.sync_thread()
        return v

    def __call__(self):  # timed; the result is ready when this returns
        self._eval()

    def values(self) -> np.ndarray:
        v = self._eval()
        fc = np.stack([np.asarray(v[c], np.float64) for c in range(3)], -1)
        c = self.cos_i[:, None]
        return np.where(c > 0, fc / np.where(c > 0, c, 1.0), 0.0).astype(F32)


# ----------------------------------------------------------------------------- checks


def max_rel_err(got: np.ndarray, ref: np.ndarray) -> float:
    got = np.asarray(got, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    if got.shape != ref.shape:
        raise AssertionError(f"shape mismatch {got.shape} vs {ref.shape}")
    if not np.all(np.isfinite(got)):
        raise AssertionError("non-finite values")
    zero = ref == 0
    if np.any(got[zero] != 0):
        raise AssertionError("non-zero where the reference is exactly 0")
    if np.all(zero):
        return 0.0
    return float(np.max(np.abs(got[~zero] - ref[~zero]) / np.abs(ref[~zero])))


# ----------------------------------------------------------------------------- timing


def _block(x):
    return x.block_until_ready() if hasattr(x, "block_until_ready") else x


def _run(fn, args, inner):
    t0 = time.perf_counter()
    for _ in range(inner):
        _block(fn(*args))
    return time.perf_counter() - t0


def calibrate(fn, args, min_time: float) -> int:
    """Smallest power-of-two-ish inner loop count whose sample lasts >= ``min_time``."""
    _block(fn(*args))  # warm-up (compilation for jitted functions)
    inner = 1
    while True:
        dt = _run(fn, args, inner)
        if dt >= min_time or inner >= 1 << 20:
            return inner
        inner = max(inner * 2, int(math.ceil(inner * 1.2 * min_time / max(dt, 1e-9))))


def time_interleaved(cases: dict, repeats: int, min_time: float) -> dict:
    """``cases``: name -> (fn, args). Returns name -> dict of timings (seconds per call)."""
    inner = {name: calibrate(fn, args, min_time) for name, (fn, args) in cases.items()}
    samples = {name: [] for name in cases}
    for _ in range(repeats):
        for name, (fn, args) in cases.items():
            samples[name].append(_run(fn, args, inner[name]) / inner[name])
    return {
        name: {
            "inner": inner[name],
            "median_s": statistics.median(s),
            "best_s": min(s),
            "samples_s": s,
        }
        for name, s in samples.items()
    }


# ----------------------------------------------------------------------------- machine info


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info() -> dict:
    try:
        affinity = sorted(os.sched_getaffinity(0))
    except AttributeError:
        affinity = None
    return {
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpus_usable": None if affinity is None else len(affinity),
        "cpu_affinity": affinity,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": getattr(jax.lib, "__version__", None) or _jaxlib_version(),
        "numpy": np.__version__,
        "brdf_fit": brdf_fit.__version__,
        "jax_devices": [str(d) for d in jax.devices()],
        "jax_enable_x64": bool(jax.config.jax_enable_x64),
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
        "loadavg_start": _loadavg(),
        "cpu_busy_before_start": cpu_busy_fraction(),
        "date_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M:%S UTC"),
    }


def cpu_busy_fraction(interval: float = 0.5):
    """Fraction of all cores busy (non-idle) over ``interval`` seconds, from /proc/stat, measured
    while this process sleeps: > 0.1 means something else is running."""

    def snap():
        with open("/proc/stat") as fh:
            vals = [int(v) for v in fh.readline().split()[1:]]
        return vals[3] + vals[4], sum(vals)  # idle + iowait, total

    try:
        i0, t0 = snap()
        time.sleep(interval)
        i1, t1 = snap()
    except (OSError, ValueError, IndexError):
        return None
    return round(1.0 - (i1 - i0) / max(t1 - t0, 1), 3)


def _loadavg():
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:  # pragma: no cover - not available on this platform
        return None


def _jaxlib_version():
    try:
        import jaxlib

        return jaxlib.__version__
    except Exception:  # pragma: no cover - informational only
        return None


# ----------------------------------------------------------------------------- main


def build_cases(n: int, rng: np.random.Generator, dirs=None):
    """name -> implementation -> (function, arguments), on ``n`` random hemisphere pairs (or on
    the given ``(wi, wo)``)."""
    if dirs is None:
        wi_np = hemisphere_directions(n, rng)
        wo_np = hemisphere_directions(n, rng)
    else:
        wi_np, wo_np = dirs
    wi = jnp.asarray(wi_np)
    wo = jnp.asarray(wo_np)
    assert wi.dtype == jnp.float32 and wo.dtype == jnp.float32

    ggx = brdf_fit.astype(registry.get("ggx-conductor").build(alpha=ALPHA), jnp.float32)
    lam = brdf_fit.astype(registry.get("lambert").build(), jnp.float32)
    eta = np.asarray(ggx.fresnel.eta)
    k = np.asarray(ggx.fresnel.k)
    params = (jnp.asarray(ALPHA, jnp.float32), ggx.fresnel.eta, ggx.fresnel.k)

    np_ggx = NumpyGGXConductor(ALPHA, ALPHA, eta, k)
    np_lam = NumpyLambert(np.asarray(lam.rho))

    sep = brdf_fit.astype(MicrofacetBRDF(distribution=GGX(ALPHA), masking=SmithSeparable(),
                                         fresnel=ConductorFresnel(eta, k)), jnp.float32)
    models = {
        "ggx-conductor": {
            "jax": (jax_model_eval, (ggx, wi, wo)),
            "jax-separable": (jax_model_eval, (sep, wi, wo)),
            "numpy": (np_ggx, (wi_np, wo_np)),
            "numpy-alloc": (np_ggx.eval_alloc, (wi_np, wo_np)),
            "jax-unpacked": (jax_ggx_unpacked, (params, wi, wo)),
            "jax-normsum": (jax_ggx_normsum, (params, wi, wo)),
            "roof-1d": (jax_roof_1d, (jnp.ones(max(1, (9 * wi.shape[0]) // 2), jnp.float32),)),
            "roof-n3": (jax_roof_n3, (wi, wo)),
        },
        "lambert": {
            "jax": (jax_model_eval, (lam, wi, wo)),
            "numpy": (np_lam, (wi_np, wo_np)),
        },
    }
    if MITSUBA["mi"] is not None:
        models["ggx-conductor"]["mitsuba-llvm"] = (MitsubaRoughConductor(ALPHA, eta, k, wi_np,
                                                                         wo_np), ())
    return models


def check(models: dict, n: int) -> dict:
    """Every implementation against ``model.eval`` (the "jax" case): rel. error <= RTOL."""
    errs = {}
    for model, cases in models.items():
        fn, args = cases["jax"]
        ref = np.asarray(fn(*args))
        if ref.dtype != np.float32:
            raise AssertionError(f"{model}: brdf_fit returned {ref.dtype}, expected float32")
        for name, (fn, args) in cases.items():
            if name == "jax" or name.startswith("roof-"):
                continue
            if name == "jax-separable":  # another function (separable G): checked by Mitsuba
                continue
            if name == "mitsuba-llvm":  # the same function as jax-separable
                sfn, sargs = cases["jax-separable"]
                out, want = fn.values(), np.asarray(sfn(*sargs))
                err = max_rel_err(out, want)
                errs[f"{model}/{name} vs jax-separable"] = err
                if not err <= RTOL:
                    raise AssertionError(f"{model}/{name} disagrees with jax-separable at N={n}: "
                                         f"max relative error {err:.3e} > {RTOL:g}")
                continue
            out = np.asarray(_block(fn(*args)))
            if out.dtype != np.float32:
                raise AssertionError(f"{model}/{name}: dtype {out.dtype}, expected float32")
            err = max_rel_err(out, ref)
            errs[f"{model}/{name}"] = err
            if not err <= RTOL:
                raise AssertionError(
                    f"{model}/{name} disagrees with brdf_fit at N={n}: max relative error "
                    f"{err:.3e} > {RTOL:g}"
                )
    return errs


def compute_ratios(rows: list) -> list:
    """Per (model, N): throughput ratios from the median and best timings.

    ``jax_over_numpy`` = t_numpy / t_jax (> 1: JAX faster); ``jax_over_numpy_alloc`` likewise
    against the allocating NumPy variant; ``normsum_slowdown`` = t_normsum / t_unpacked and
    ``library_over_unpacked`` = t_jax / t_unpacked (> 1: slower than the hand-unpacked kernel);
    ``jax_over_roofline`` = t_roof-1d / t_jax (the fraction of the memory-bandwidth bound the
    model reaches; meaningful at large N, where both are bandwidth- or compute-bound rather than
    dispatch-bound).
    """
    by = {(r["model"], r["n"], r["impl"]): r for r in rows}
    out = []
    for model, n, impl in by:
        if impl != "jax":
            continue
        rec = {"model": model, "n": n}
        pairs = {
            "jax_over_numpy": ("numpy", "jax"),
            "jax_over_numpy_alloc": ("numpy-alloc", "jax"),
            "normsum_slowdown": ("jax-normsum", "jax-unpacked"),
            "library_over_unpacked": ("jax", "jax-unpacked"),
            "jax_over_roofline": ("roof-1d", "jax"),
            "jax_over_mitsuba": ("mitsuba-llvm", "jax"),
            "separable_over_mitsuba": ("mitsuba-llvm", "jax-separable"),
        }
        for key, (num, den) in pairs.items():
            if (model, n, num) in by and (model, n, den) in by:
                a, b = by[(model, n, num)], by[(model, n, den)]
                rec[f"{key}_median"] = a["median_s"] / b["median_s"]
                rec[f"{key}_best"] = a["best_s"] / b["best_s"]
        out.append(rec)
    return out


def fmt_rate(x: float) -> str:
    return f"{x:.3g}"


def write_markdown(path: Path, command: str, info: dict, rows: list, ratios: list,
                   args) -> None:
    lines = [
        "# Evaluation throughput: brdf_fit under jax.jit vs a NumPy float32 baseline",
        "",
        "Command:",
        "",
        "```",
        command,
        "```",
        "",
        f"- date: {info['date_utc']}",
        f"- CPU: {info['cpu_model']} ({info['cpu_count']} logical cores, "
        f"{info['cpus_usable']} usable: affinity {info['cpu_affinity']}"
        f"{'' if info['cpus_usable'] == info['cpu_count'] else ', pinned (e.g. taskset)'})",
        f"- platform: {info['platform']}, Python {info['python']}",
        f"- jax {info['jax']} (jaxlib {info['jaxlib']}, devices {', '.join(info['jax_devices'])}, "
        f"x64 {'on' if info['jax_enable_x64'] else 'off'}), numpy {info['numpy']}, "
        f"brdf_fit {info['brdf_fit']}",
        f"- float32 throughout; alpha = {ALPHA}; default gold eta/k (RGB, 3 channels); "
        "directions uniform on the upper hemisphere",
        f"- {args.repeats} samples per implementation and size (interleaved), each sample "
        f">= {args.min_time:g} s of back-to-back calls, every call `block_until_ready()`",
        f"- every implementation agrees with `model.eval` (`mitsuba-llvm`: with "
        f"`jax-separable`) to <= {RTOL:g} relative "
        "(checked in the run on the benchmark inputs and on full-sphere directions with "
        "degenerate pairs; max errors in eval.json)",
        f"- CPU busy just before the start (all cores, this process asleep): "
        f"{info['cpu_busy_before_start']}; load average (1, 5, 15 min) at start "
        f"{info['loadavg_start']}, at end {info['loadavg_end']}",
        "",
        "## Ratios",
        "",
        "Throughput ratio jax/numpy = t_numpy / t_jax (> 1: the jitted brdf_fit model is faster); "
        "normsum slowdown = t_jax-normsum / t_jax-unpacked; library/unpacked = t_jax / "
        "t_jax-unpacked (> 1: the library's kernel is slower than the hand-written one); "
        "jax/roofline = t_roof-1d / t_jax (fraction of the memory-bandwidth bound reached: "
        "`roof-1d` moves the kernel's 36 bytes per pair, see the implementations below); "
        "jax/mitsuba = t_mitsuba-llvm / t_jax (> 1: brdf_fit faster than Mitsuba 3's LLVM "
        "kernel; the registry `ggx-conductor` has the height-correlated Smith G, Mitsuba the "
        "separable one, the same work up to a few operations) and separable/mitsuba = "
        "t_mitsuba-llvm / t_jax-separable (the same function as Mitsuba's). "
        + (f"Mitsuba {info['mitsuba']['version']}, `llvm_ad_rgb`, libLLVM "
           f"`{info['mitsuba']['libllvm']}`." if info["mitsuba"]["why"] is None else
           f"Mitsuba rows left out: {info['mitsuba']['why']}."),
        "",
        "| model | N | jax/numpy (median) | jax/numpy (best) | jax/numpy-alloc (median) "
        "| normsum slowdown (median) | library/unpacked (median) | jax/roofline (median) "
        "| jax/mitsuba (median) | jax/mitsuba (best) | separable/mitsuba (median) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]

    def cell(rec, key, bold=False):
        if key not in rec:
            return ""
        txt = f"{rec[key]:.2f}"
        return f"**{txt}**" if bold else txt

    for rec in sorted(ratios, key=lambda r: (r["model"], r["n"])):
        lines.append(
            f"| {rec['model']} | {rec['n']:.0e} | {cell(rec, 'jax_over_numpy_median', True)} "
            f"| {cell(rec, 'jax_over_numpy_best')} | {cell(rec, 'jax_over_numpy_alloc_median')} "
            f"| {cell(rec, 'normsum_slowdown_median')} "
            f"| {cell(rec, 'library_over_unpacked_median')} "
            f"| {cell(rec, 'jax_over_roofline_median')} "
            f"| {cell(rec, 'jax_over_mitsuba_median', True)} "
            f"| {cell(rec, 'jax_over_mitsuba_best')} "
            f"| {cell(rec, 'separable_over_mitsuba_median')} |"
        )
    lines += [
        "",
        "## Timings",
        "",
        "| model | impl | N | median s/call | best s/call | evals/s (median) | evals/s (best) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['model']} | {r['impl']} | {r['n']:.0e} | {r['median_s']:.3e} | "
            f"{r['best_s']:.3e} | {fmt_rate(r['evals_per_s_median'])} | "
            f"{fmt_rate(r['evals_per_s_best'])} |"
        )
    lines += [
        "",
        "Implementations: `jax` = `jax.jit` of the registry model's `eval` (model passed as a jit "
        "argument); `numpy` = the vectorised NumPy float32 baseline in `bench_eval.py`; "
        "`numpy-alloc` = the same NumPy arithmetic as plain expressions (temporaries allocated "
        "per call); `jax-unpacked` / `jax-normsum` = the baseline's formulas in `jnp`, written on "
        "unpacked components / with `jnp.linalg.norm(.., keepdims=True)` and `jnp.sum(a * b, -1)`; "
        "`roof-1d` = `x * 2.0` on a flat float32 array of 4.5 N elements (36 bytes per pair moved, "
        "one stream: the bandwidth roofline), `roof-n3` = `wi + wo` on the (N, 3) inputs (the same "
        "bytes in the kernel's layout; XLA's tiled emitter does not vectorise it across rows); "
        "`jax-separable` = the public API's GGX + separable Smith + conductor Fresnel "
        "microfacet model; `mitsuba-llvm` = Mitsuba 3's `roughconductor` through `BSDF.eval` "
        "(llvm_ad_rgb, resident opaque inputs, traced and evaluated every call, checked "
        "against `jax-separable`). One evaluation = one (wi, wo) pair, all 3 channels.",
        "",
    ]
    path.write_text("\n".join(lines))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", nargs="+", type=float, default=[1e3, 1e4, 1e5, 1e6],
                    help="batch sizes (number of (wi, wo) pairs)")
    ap.add_argument("--repeats", type=int, default=7, help="timing samples per implementation")
    ap.add_argument("--min-time", type=float, default=0.05,
                    help="minimum duration of one timing sample in seconds")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results")
    ap.add_argument("--libllvm", default=None,
                    help="libLLVM for Mitsuba's llvm variant (default: DRJIT_LIBLLVM_PATH)")
    ap.add_argument("--no-mitsuba", action="store_true", help="leave the Mitsuba rows out")
    args = ap.parse_args(argv)
    if args.no_mitsuba:
        MITSUBA["why"] = "--no-mitsuba"
    else:
        load_mitsuba(args.libllvm)
        if MITSUBA["mi"] is None:
            print(f"mitsuba-llvm rows left out: {MITSUBA['why']}", file=sys.stderr)
    if jax.config.jax_enable_x64:
        raise SystemExit("run with x64 disabled (JAX_ENABLE_X64 unset): this is a float32 bench")

    command = "python " + shlex.join([sys.argv[0], *(sys.argv[1:] if argv is None else argv)])
    info = machine_info()
    info["mitsuba"] = {k: MITSUBA[k] for k in ("version", "libllvm", "why")}
    busy = info["cpu_busy_before_start"]
    if busy is not None and busy > 0.1:
        print(f"warning: {busy:.0%} of the CPU was busy before the start: another process is "
              "running; the timings (small N especially) will be noisy", file=sys.stderr)
    t_start = time.perf_counter()
    rng = np.random.default_rng(SEED)
    rows, errors = [], {}
    wi_e, wo_e = edge_directions(4096, rng)
    errors["edge"] = check(build_cases(0, rng, (wi_e, wo_e)), wi_e.shape[0])
    for n in [int(s) for s in args.sizes]:
        models = build_cases(n, rng)
        errors[str(n)] = check(models, n)
        for model, cases in models.items():
            res = time_interleaved(cases, args.repeats, args.min_time)
            for impl, r in res.items():
                row = {
                    "model": model,
                    "impl": impl,
                    "n": n,
                    **r,
                    "evals_per_s_median": n / r["median_s"],
                    "evals_per_s_best": n / r["best_s"],
                }
                rows.append(row)
                print(
                    f"{model:14s} {impl:13s} N={n:>8d}  median {r['median_s']:.3e} s  "
                    f"best {r['best_s']:.3e} s  {n / r['median_s']:.3g} evals/s",
                    flush=True,
                )
    elapsed = time.perf_counter() - t_start

    info["loadavg_end"] = _loadavg()
    ratios = compute_ratios(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    write_markdown(args.out / "eval.md", command, info, rows, ratios, args)
    payload = {
        "command": command,
        "machine": info,
        "settings": {
            "sizes": [int(s) for s in args.sizes],
            "repeats": args.repeats,
            "min_time_s": args.min_time,
            "alpha": ALPHA,
            "dtype": "float32",
            "seed": SEED,
            "rtol": RTOL,
        },
        "max_rel_err_vs_brdf_fit": errors,
        "results": rows,
        "ratios": ratios,
        "elapsed_s": elapsed,
    }
    (args.out / "eval.json").write_text(json.dumps(payload, indent=2) + "\n")
    print("\njax/numpy throughput ratio (median):")
    for r in ratios:
        print(f"  {r['model']:14s} N={r['n']:>8d}  {r['jax_over_numpy_median']:.2f} "
              f"(best {r['jax_over_numpy_best']:.2f})"
              + (f"  jax/mitsuba {r['jax_over_mitsuba_median']:.2f} "
                 f"(best {r['jax_over_mitsuba_best']:.2f})" if "jax_over_mitsuba_median" in r
                 else ""))
    print(f"wrote {args.out / 'eval.md'} and {args.out / 'eval.json'} ({elapsed:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
