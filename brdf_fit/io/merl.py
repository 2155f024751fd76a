"""MERL BRDF binary files (``*.binary``, the layout of the public ``BRDFRead.cpp``).

Layout (little-endian): a header of 3 ``int32`` = ``(90, 90, 180)`` (n_theta_h, n_theta_d, n_phi_d),
then three channel blocks R, G, B of ``90*90*180`` ``float64`` each; inside a block the index is
``i_phi_d + 180 * (i_theta_d + 90 * i_theta_h)`` (phi_d fastest). A stored raw value times the
channel scale ``(1/1500, 1.15/1500, 1.66/1500)`` is the BRDF in 1/sr (not multiplied by the
cosine). Negative raw values (written as -1) mean missing or below-horizon data. File size:
34,992,012 bytes.

Index functions (BRDFRead semantics, floor then clamp to ``[0, n-1]``)::

    i_theta_h = floor(sqrt(theta_h / (pi/2) * 90 * 90))      # non-linear, dense near specular
    i_theta_d = floor(theta_d / (pi/2) * 90)
    i_phi_d   = floor(phi_d / pi * 180), with phi_d += pi if phi_d < 0   (reciprocity fold)

**Sample positions.** :func:`write_merl` evaluates the model at the **bin centres**
(``theta_h = ((i + 1/2)/90)^2 pi/2``, ``theta_d = (j + 1/2)/90 pi/2``, ``phi_d = (k + 1/2)/180 pi``,
``phi_h = 0``), and :func:`read_merl` / :func:`merl_bin_centres` report samples there. Every centre
maps back to its own bin under the index functions, so write -> read -> lookup is exact at the
centres: the positions and bins exactly, the values to two roundings (the file holds
``fl(f / scale)`` and readers compute ``raw * scale`` as ``BRDFRead.cpp`` does; about 10-17% of
float64 values cannot be reproduced bit for bit by any raw value under that product).
Interpolating readers that assume lower-edge positions (e.g. Sztrajman's ``eval_interp``)
are then offset by half a bin; nearest-bin lookup at arbitrary directions has errors of a few %.

The MERL measured data is licensed for research and non-commercial use; ship only synthetic files.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from brdf_fit.data import DataError, GonioData

__all__ = [
    "MERL_DIMS",
    "MERL_FILE_SIZE",
    "MERL_MISSING",
    "MERL_SCALES",
    "is_merl_file",
    "merl_bin_centres",
    "merl_interpolate",
    "merl_slice_centres",
    "half_diff_angles",
    "merl_indices",
    "merl_lookup",
    "read_merl",
    "read_merl_table",
    "write_merl",
]

N_TH, N_TD, N_PD = 90, 90, 180
MERL_DIMS = (N_TH, N_TD, N_PD)
N_BINS = N_TH * N_TD * N_PD
HEADER_BYTES = 12
MERL_FILE_SIZE = HEADER_BYTES + 3 * N_BINS * 8  # 34,992,012
#: Per-channel scale: BRDF [1/sr] = raw * scale.
MERL_SCALES = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
#: Value of a missing / below-horizon bin in a table from :func:`read_merl_table` (raw -1 is
#: stored in the file; tables keep the MERL convention "negative = missing" as exactly -1.0).
MERL_MISSING = -1.0

_HALF_PI = np.pi / 2.0
_Y = np.array([0.0, 1.0, 0.0])
_Z = np.array([0.0, 0.0, 1.0])


def _rotate(v, axis, angle):
    """Rodrigues' rotation of ``v`` (N, 3) about the unit ``axis`` (3,) by ``angle`` (N,)."""
    c = np.cos(angle)[:, None]
    s = np.sin(angle)[:, None]
    dot = (v @ axis)[:, None]
    return v * c + axis[None, :] * dot * (1.0 - c) + np.cross(axis[None, :], v) * s


def _half_diff(wi, wo):
    """(theta_h, theta_d, phi_d) of direction pairs, as ``std_coords_to_half_diff_coords``."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    theta_h = np.arccos(np.clip(h[:, 2], -1.0, 1.0))
    phi_h = np.arctan2(h[:, 1], h[:, 0])
    d = _rotate(_rotate(wi, _Z, -phi_h), _Y, -theta_h)
    theta_d = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    phi_d = np.arctan2(d[:, 1], d[:, 0])
    return theta_h, theta_d, phi_d


def half_diff_angles(wi, wo) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(theta_h, theta_d, phi_d)`` of ``(N, 3)`` direction pairs (radians), as the MERL
    reference code's ``std_coords_to_half_diff_coords`` computes them."""
    return _half_diff(np.atleast_2d(np.asarray(wi, np.float64)),
                      np.atleast_2d(np.asarray(wo, np.float64)))


def merl_indices(wi, wo) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bin indices ``(i_theta_h, i_theta_d, i_phi_d)`` of direction pairs (N, 3), exactly as the
    MERL reference code computes them (floor, then clamp)."""
    wi = np.atleast_2d(np.asarray(wi, np.float64))
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    theta_h, theta_d, phi_d = _half_diff(wi, wo)
    # theta_h: ((theta_h / (pi/2)) * 90) * 90, sqrt, truncate; theta_h <= 0 -> 0
    t = np.sqrt(np.maximum(theta_h / _HALF_PI * N_TH * N_TH, 0.0))
    ith = np.where(theta_h <= 0.0, 0, np.clip(np.floor(t), 0, N_TH - 1)).astype(np.int64)
    itd = np.clip(np.floor(theta_d / _HALF_PI * N_TD), 0, N_TD - 1).astype(np.int64)
    phi_d = np.where(phi_d < 0.0, phi_d + np.pi, phi_d)
    ipd = np.clip(np.floor(phi_d / np.pi * (2 * N_PD) / 2), 0, N_PD - 1).astype(np.int64)
    return ith, itd, ipd


def merl_bin_centres() -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)``, each (1458000, 3), of every bin centre in file order (phi_h = 0).

    Some centres lie below the horizon (``wi[:, 2] <= 0`` or ``wo[:, 2] <= 0``); those bins are
    stored as missing. Made one theta_h row at a time (the difference directions of a row are
    the same in every row), so that nothing but the two results is ever full size (the whole
    grid at once held ~260 MB of temporaries while a MERL file was read)."""
    itd, ipd = np.meshgrid(np.arange(N_TD), np.arange(N_PD), indexing="ij")
    theta_d = (itd.ravel() + 0.5) / N_TD * _HALF_PI
    phi_d = (ipd.ravel() + 0.5) / N_PD * np.pi
    st = np.sin(theta_d)
    d = np.stack([st * np.cos(phi_d), st * np.sin(phi_d), np.cos(theta_d)], -1)
    wi = np.empty((N_TH, N_TD * N_PD, 3))
    wo = np.empty_like(wi)
    for i in range(N_TH):
        theta_h = np.full(d.shape[0], ((i + 0.5) / N_TH) ** 2 * _HALF_PI)
        wi[i] = _rotate(d, _Y, theta_h)
        h = np.stack([np.sin(theta_h), np.zeros_like(theta_h), np.cos(theta_h)], -1)
        wo[i] = 2.0 * np.sum(wi[i] * h, -1, keepdims=True) * h - wi[i]
    return wi.reshape(N_BINS, 3), wo.reshape(N_BINS, 3)


def merl_slice_centres(i_phi_d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(wi, wo, theta_h, theta_d)`` of the bin centres of one ``phi_d`` bin: directions
    ``(90, 90, 3)`` indexed ``[i_theta_h, i_theta_d]`` (made as :func:`merl_bin_centres` makes
    them, phi_h = 0), and the centres' angles in radians (``(90,)`` each). The
    Rusinkiewicz "image slice" at ``phi_d = 90`` degrees is bin 90."""
    if not 0 <= int(i_phi_d) < N_PD:
        raise ValueError(f"merl_slice_centres: the phi_d bin must be in [0, {N_PD}), got {i_phi_d}")
    theta_h = ((np.arange(N_TH) + 0.5) / N_TH) ** 2 * _HALF_PI
    theta_d = (np.arange(N_TD) + 0.5) / N_TD * _HALF_PI
    phi_d = (int(i_phi_d) + 0.5) / N_PD * np.pi
    st = np.sin(theta_d)
    d = np.stack([st * np.cos(phi_d), st * np.sin(phi_d), np.cos(theta_d)], -1)  # (90, 3)
    th = np.repeat(theta_h, N_TD)
    dd = np.tile(d, (N_TH, 1))
    wi = _rotate(dd, _Y, th)
    h = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1)
    wo = 2.0 * np.sum(wi * h, -1, keepdims=True) * h - wi
    return wi.reshape(N_TH, N_TD, 3), wo.reshape(N_TH, N_TD, 3), theta_h, theta_d


def _evaluate(fn_or_model, wi, wo, chunk):
    if hasattr(fn_or_model, "eval"):
        import jax  # a BRDF model: compile its eval once (eager dispatch is ~100x slower here)

        model = fn_or_model
        f = jax.jit(lambda a, b: model.eval(a, b))
    else:
        f = fn_or_model
    if not callable(f):
        raise TypeError("write_merl needs a model with .eval(wi, wo) or a callable f(wi, wo)")
    out = []
    for s in range(0, wi.shape[0], chunk):
        a, b = wi[s:s + chunk], wo[s:s + chunk]
        m = a.shape[0]
        padded = f is not fn_or_model and m < chunk and s > 0
        if padded:
            # pad the last chunk to the compiled shape (a normal-incidence pair is always valid)
            pad = np.tile(np.array([[0.0, 0.0, 1.0]]), (chunk - m, 1))
            a, b = np.concatenate([a, pad]), np.concatenate([b, pad])
        v = np.asarray(f(a, b), dtype=np.float64)
        if padded:
            v = v[:m]
        if v.ndim == 1:
            v = v[:, None]
        v = np.broadcast_to(v, (v.shape[0], 3)) if v.shape[-1] == 1 else v
        if v.shape != (min(chunk, wi.shape[0] - s), 3):
            raise DataError(
                f"write_merl: the model returned shape {v.shape} for "
                f"{min(chunk, wi.shape[0] - s)} direction pairs; expected (N, 3) RGB (or (N, 1))"
            )
        out.append(v)
    return np.concatenate(out, 0) if out else np.zeros((0, 3))


def write_merl(path, fn_or_model, chunk: int = 262144) -> None:
    """Write a synthetic MERL binary of ``fn_or_model`` (an ``AbstractBRDF`` or a callable
    ``f(wi, wo) -> (N, 3)`` BRDF in 1/sr, without the cosine) sampled at the **bin centres**.

    Bins whose centre has ``cos(theta_i) <= 0`` or ``cos(theta_o) <= 0`` are written as raw -1.
    A non-finite or negative model value at a valid bin raises :class:`DataError`."""
    wi, wo = merl_bin_centres()
    valid = (wi[:, 2] > 0.0) & (wo[:, 2] > 0.0)
    f = np.full((N_BINS, 3), np.nan)
    f[valid] = _evaluate(fn_or_model, wi[valid], wo[valid], chunk)
    bad = valid[:, None] & ~(np.isfinite(f) & (f >= 0.0))
    if bad.any():
        i = int(np.flatnonzero(bad.any(-1))[0])
        raise DataError(
            f"write_merl: the model value at bin {np.unravel_index(i, MERL_DIMS)} "
            f"(wi={wi[i].tolist()}, wo={wo[i].tolist()}) is {f[i].tolist()}; MERL stores "
            "finite non-negative BRDF values"
        )
    raw = np.where(valid[:, None], f / MERL_SCALES[None, :], -1.0)
    with open(path, "wb") as fh:
        fh.write(np.asarray(MERL_DIMS, dtype="<i4").tobytes())
        fh.write(np.ascontiguousarray(raw.T, dtype="<f8").tobytes())


def _read_raw(path) -> np.ndarray:
    """Raw payload as (3, 90, 90, 180) after checking header and size: both from the first
    12 bytes and the file's size, before the payload is read (a 6 GiB file with a valid header
    was read whole, 6.5 GB of memory, before its size was refused)."""
    name = os.fspath(path)
    try:
        size = os.path.getsize(name)
        with open(name, "rb") as fh:
            head = fh.read(HEADER_BYTES)
            if size < HEADER_BYTES:
                raise DataError(
                    f"{name}: {size} bytes is too short for a MERL header (3 int32 = 12 bytes); "
                    "the file is truncated or not a MERL binary")
            dims = tuple(int(x) for x in np.frombuffer(head, dtype="<i4"))
            if dims != MERL_DIMS:
                raise DataError(
                    f"{name}: MERL header dims {dims}, expected {MERL_DIMS} "
                    "(n_theta_h, n_theta_d, n_phi_d); not a MERL BRDF binary")
            if size != MERL_FILE_SIZE:
                what = ("truncated" if size < MERL_FILE_SIZE
                        else f"{size - MERL_FILE_SIZE:,} bytes too long")
                raise DataError(
                    f"{name}: wrong size {size:,} bytes, a 90x90x180 MERL file has "
                    f"{MERL_FILE_SIZE:,} bytes (the file is {what})")
            payload = np.empty(3 * N_BINS, dtype="<f8")
            got = fh.readinto(memoryview(payload).cast("B"))
    except OSError as e:
        raise DataError(f"{name}: cannot read MERL file ({e.strerror or e})") from None
    if got != payload.nbytes:  # the file shrank between the size check and the read
        raise DataError(f"{name}: read {got:,} of {payload.nbytes:,} payload bytes (the file "
                        "changed while it was read)")
    raw = payload.astype(np.float64, copy=False).reshape(3, N_TH, N_TD, N_PD)
    if not np.isfinite(raw).all():
        c, i, j, k = (int(x[0]) for x in np.nonzero(~np.isfinite(raw)))
        raise DataError(
            f"{name}: non-finite value {raw[c, i, j, k]} in channel {'RGB'[c]} at bin "
            f"(i_theta_h={i}, i_theta_d={j}, i_phi_d={k})"
        )
    return raw


def is_merl_file(path) -> bool:
    """True if ``path`` has the MERL size and header (cheap sniff; reads 12 bytes)."""
    try:
        if os.path.getsize(path) != MERL_FILE_SIZE:
            return False
        with open(path, "rb") as fh:
            head = fh.read(HEADER_BYTES)
    except OSError:
        return False
    return tuple(int(x) for x in np.frombuffer(head, dtype="<i4")) == MERL_DIMS


def read_merl_table(path) -> np.ndarray:
    """Dense table (3, 90, 90, 180) of BRDF values in 1/sr (channels R, G, B); missing bins
    (negative raw) are exactly :data:`MERL_MISSING` (-1.0). Use with :func:`merl_lookup`."""
    raw = _read_raw(path)
    table = raw * MERL_SCALES[:, None, None, None]
    return np.where(raw < 0.0, MERL_MISSING, table)


def merl_lookup(table, wi, wo) -> np.ndarray:
    """Nearest-bin lookup (BRDFRead semantics) in a table from :func:`read_merl_table`:
    (N, 3) RGB BRDF in 1/sr. Missing bins, and pairs with ``wi`` or ``wo`` at or below the
    horizon, return :data:`MERL_MISSING` (-1.0)."""
    table = np.asarray(table, np.float64)
    if table.shape != (3, *MERL_DIMS):
        raise DataError(f"merl_lookup: table must have shape (3, 90, 90, 180), got {table.shape}")
    wi = np.atleast_2d(np.asarray(wi, np.float64))
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    if wi.shape != wo.shape or wi.shape[-1] != 3 or wi.ndim != 2:
        raise DataError(f"merl_lookup: wi and wo must be (N, 3), got {wi.shape} and {wo.shape}")
    ith, itd, ipd = merl_indices(wi, wo)
    out = table[:, ith, itd, ipd].T
    below = (wi[:, 2] <= 0.0) | (wo[:, 2] <= 0.0)
    return np.where(below[:, None], MERL_MISSING, out)


def merl_interpolate(table, wi, wo) -> np.ndarray:
    """Trilinear interpolation between bin centres in a table from :func:`read_merl_table`:
    (N, 3) RGB BRDF in 1/sr. The coordinates are the bins' own (``theta_h`` in MERL's
    square-root index, ``theta_d`` and ``phi_d`` linear), so a bin centre returns the bin's
    value (to the rounding of its angles: 1e-11 relative); ``theta_h`` and ``theta_d`` are
    clamped at the first and last centres, ``phi_d`` wraps with period pi (the table's
    reciprocity fold). Missing neighbours are left out and the others' weights renormalised;
    a pair with no valid neighbour, or a direction at or below the horizon, returns
    :data:`MERL_MISSING`. Where :func:`merl_lookup` (the nearest bin) steps from bin to bin,
    this is continuous (a rendered highlight shows no bin edges)."""
    table = np.asarray(table, np.float64)
    if table.shape != (3, *MERL_DIMS):
        raise DataError(f"merl_interpolate: table must have shape (3, 90, 90, 180), got "
                        f"{table.shape}")
    wi = np.atleast_2d(np.asarray(wi, np.float64))
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    theta_h, theta_d, phi_d = _half_diff(wi, wo)
    phi_d = np.mod(phi_d, np.pi)
    th = np.clip(np.sqrt(np.maximum(theta_h, 0.0) / _HALF_PI) * N_TH - 0.5, 0.0, N_TH - 1.0)
    td = np.clip(theta_d / _HALF_PI * N_TD - 0.5, 0.0, N_TD - 1.0)
    tp = phi_d / np.pi * N_PD - 0.5  # wraps: -0.5 is halfway between bins 179 and 0
    corners = []
    for t, n, wrap in ((th, N_TH, False), (td, N_TD, False), (tp, N_PD, True)):
        lo = np.floor(t)
        frac = t - lo
        lo = lo.astype(np.int64)
        hi = lo + 1
        if wrap:
            lo, hi = np.mod(lo, n), np.mod(hi, n)
        else:
            hi = np.minimum(hi, n - 1)
        corners.append(((lo, 1.0 - frac), (hi, frac)))
    total = np.zeros((wi.shape[0], 3))
    weight = np.zeros((wi.shape[0], 3))
    for (ih, wh) in corners[0]:
        for (id_, wd) in corners[1]:
            for (ip, wp) in corners[2]:
                v = table[:, ih, id_, ip].T
                w = (wh * wd * wp)[:, None] * (v >= 0.0)
                total += w * np.where(v >= 0.0, v, 0.0)
                weight += w
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(weight > 0.0, total / weight, MERL_MISSING)
    below = (wi[:, 2] <= 0.0) | (wo[:, 2] <= 0.0)
    return np.where(below[:, None], MERL_MISSING, out)


def read_merl(path) -> GonioData:
    """Every valid bin (all three channels present, both directions above the horizon) as one
    sample at its bin centre; channels R, G, B; values BRDF in 1/sr."""
    raw = _read_raw(path).reshape(3, N_BINS)
    wi, wo = merl_bin_centres()
    keep = (raw >= 0.0).all(0) & (wi[:, 2] > 0.0) & (wo[:, 2] > 0.0)
    if not keep.any():
        raise DataError(f"{os.fspath(path)}: no valid bin: every bin above the horizon is "
                        "missing (a negative raw value in some channel)")
    value = (raw[:, keep] * MERL_SCALES[:, None]).T
    return GonioData(
        wi=wi[keep],
        wo=wo[keep],
        value=value,
        channels=("R", "G", "B"),
        metadata={
            "source": os.fspath(path),
            "format": "merl",
            "sample_positions": "bin centres",
            "n_missing_bins": int(N_BINS - keep.sum()),
        },
    )


#: Type of the callables accepted by :func:`write_merl`.
BRDFCallable = Callable[[np.ndarray, np.ndarray], np.ndarray]
