"""RGL-EPFL measured materials (``*.bsdf``): the adaptive parameterisation of Dupuy & Jakob,
"An adaptive parameterization for efficient material acquisition and rendering", ACM TOG 37(6),
2018, as Mitsuba 3's ``measured`` plugin reads it (``src/bsdfs/measured.cpp``, with
``Marginal2D`` of ``include/mitsuba/core/distr_2d.h``; both read for this module, none of their
code copied).

**The file** is a *tensor file* (Mitsuba's ``TensorFile``, ``src/core/tensor.cpp``): the 12
bytes ``tensor_file\\0``, a version ``(1, 0)``, a ``uint32`` field count, then per field its
name (``uint16`` length + UTF-8), ``uint16`` rank, ``uint8`` type code (1-11: u8, i8, u16, i16,
u32, i32, u64, i64, f16, f32, f64), ``uint64`` byte offset and ``uint64`` extents, all
little-endian, and the fields' data at their offsets. A material holds ``description`` (u8
text), ``jacobian`` (one u8 flag), ``theta_i`` and ``phi_i`` (f32, radians: the incident
directions the tables were measured at), ``ndf`` and ``sigma`` (f32, 2-D), ``vndf`` and
``luminance`` (f32, ``[phi_i, theta_i, rows, cols]``), and ``rgb`` (f32, ``[phi_i, theta_i, 3,
rows, cols]``) or ``spectra`` with ``wavelengths`` (nm).

**Evaluation** at an incident ``wi`` and outgoing ``wo`` (both above the surface):

1. a material measured over a part of the azimuths (``phi_i`` spanning ``2 pi / r``, ``r`` = 2
   or 4) is reduced to it by flipping the signs of x and y of both directions as the plugin
   does; an isotropic one (at most two ``phi_i``) is not;
2. ``m = normalize(wi + wo)``; the unit coordinates ``u(theta) = sqrt(2 theta / pi)`` and
   ``u(phi) = (phi + pi) / (2 pi)``, with ``phi_m - phi_i`` for an isotropic material
   (wrapped into [0, 1));
3. the sample ``s`` is the inverse of the VNDF warp at ``u_m``: the continuous marginal /
   conditional inversion of the bilinear interpolant of ``vndf`` (normalised per slice),
   interpolated linearly in ``phi_i`` and ``theta_i`` (:class:`_Warp`);
4. each channel is the bilinear interpolant of ``rgb`` (or ``spectra``) at ``s``, interpolated
   in ``phi_i``, ``theta_i`` (and the channel index), and with ``jacobian`` set it is multiplied
   by ``ndf(u_m) / (4 sigma(u_wi))``.

That value is what the plugin's ``eval`` returns: the BRDF times the cosine of ``wo``, Mitsuba's
convention; :meth:`RGLMaterial.eval` divides it by ``wo.z``. The table's incident direction is
the light's in the acquisition (``wi`` here, as everywhere in this package: toward the light).
When Mitsuba renders the material it passes the direction toward the camera as its ``wi``;
for a reciprocal material the two readings agree.

Agreement with the plugin (``tests/io/test_rgl.py``): files written for the test (an isotropic,
an anisotropic and a half-azimuth material with random tables), evaluated here in float64 from
their float32 tables and by Mitsuba 3.9.1's ``scalar_rgb`` variant in float32 at random and at
grazing directions: at most 8.5e-6 relative, median 3.5e-7 (float32 rounding through the
plugin's chain of square roots, arc functions and CDF quotients). For a file with at most two
``phi_i`` the plugin leaves its azimuth reduction unset (an uninitialised member); for an
isotropic material (tables symmetric in azimuth, ``ndf`` and ``sigma`` independent of it) every
reduction gives the same value, the one computed here without one.
"""

from __future__ import annotations

import os
import struct

import numpy as np

from brdf_fit.core.atomic import write_bytes_atomic
from brdf_fit.core.limits import LimitError, check_bytes
from brdf_fit.data import DataError, GonioData

__all__ = ["RGLMaterial", "read_tensor_file", "write_tensor_file", "read_rgl",
           "default_directions"]

_MAGIC = b"tensor_file\0"
#: Mitsuba's type codes (``Struct::Type``) -> NumPy (little-endian)
_TYPES = {1: "<u1", 2: "<i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8", 8: "<i8",
          9: "<f2", 10: "<f4", 11: "<f8"}
_CODES = {np.dtype(v).newbyteorder("<"): k for k, v in _TYPES.items()}
#: the most fields and the highest rank a tensor file may declare (a header past them is not a
#: material: refused before any allocation)
MAX_FIELDS = 256
MAX_RANK = 16


def read_tensor_file(path) -> dict[str, np.ndarray]:
    """Every field of a tensor file (module docstring) as a NumPy array (text fields stay
    ``uint8``). A truncated or inconsistent file, or one whose fields would exceed the memory
    limit (:mod:`brdf_fit.core.limits`), raises :class:`~brdf_fit.data.DataError` naming it."""
    name = os.fspath(path)
    try:
        size = os.path.getsize(name)
        with open(name, "rb") as f:
            head = f.read(18)
            if len(head) < 18 or head[:12] != _MAGIC:
                raise DataError(f"{name}: not a tensor file (no 'tensor_file' header)")
            if head[12:14] != b"\x01\x00":
                raise DataError(f"{name}: tensor file version {head[12]}.{head[13]}, "
                                "expected 1.0")
            (count,) = struct.unpack("<I", head[14:18])
            if count > MAX_FIELDS:
                raise DataError(f"{name}: declares {count} fields (at most {MAX_FIELDS})")
            fields, total = {}, 0
            for _ in range(count):
                fname, dtype, offset, shape = _field_header(f, name)
                count_items = int(np.prod(shape, dtype=object))
                nbytes = count_items * dtype.itemsize
                if offset + nbytes > size:
                    raise DataError(f"{name}: field {fname!r} ({'x'.join(map(str, shape))} "
                                    f"{dtype.name}) runs past the end of the file "
                                    "(truncated?)")
                total += nbytes
                fields[fname] = (dtype, offset, shape, count_items)
            check_bytes(total, f"{name}: its fields")
            out = {}
            for fname, (dtype, offset, shape, count_items) in fields.items():
                f.seek(offset)
                out[fname] = np.fromfile(f, dtype=dtype, count=count_items).reshape(shape)
            return out
    except LimitError as e:
        raise DataError(str(e)) from None
    except OSError as e:
        raise DataError(f"{name}: cannot read ({e.strerror or e})") from None


def _field_header(f, name):
    def take(fmt):
        n = struct.calcsize(fmt)
        raw = f.read(n)
        if len(raw) < n:
            raise DataError(f"{name}: the field table is truncated")
        return struct.unpack(fmt, raw)

    (length,) = take("<H")
    raw = f.read(length)
    if len(raw) < length:
        raise DataError(f"{name}: the field table is truncated")
    fname = raw.decode("utf-8", errors="replace")
    rank, code, offset = take("<HBQ")
    if code not in _TYPES:
        raise DataError(f"{name}: field {fname!r} has unknown type code {code}")
    if rank > MAX_RANK:
        raise DataError(f"{name}: field {fname!r} has rank {rank} (at most {MAX_RANK})")
    shape = take("<" + "Q" * rank) if rank else ()
    return fname, np.dtype(_TYPES[code]), offset, tuple(int(s) for s in shape)


def write_tensor_file(path, **fields) -> None:
    """Write ``fields`` (arrays, or ``str`` for text) as a tensor file, each field's data at an
    8-byte aligned offset (as Mitsuba's own writer, ``tensor_io.write``, aligns them)."""
    arrays = {k: (np.frombuffer(v.encode("utf-8"), np.uint8) if isinstance(v, str)
                  else np.ascontiguousarray(v)) for k, v in fields.items()}
    head_size = 18 + sum(2 + len(k.encode()) + 2 + 1 + 8 + 8 * v.ndim for k, v in arrays.items())
    header = bytearray(_MAGIC + b"\x01\x00" + struct.pack("<I", len(arrays)))
    body = bytearray()
    for k, v in arrays.items():
        body += b"\0" * ((-(head_size + len(body))) % 8)
        label = k.encode()
        header += struct.pack("<H", len(label)) + label
        header += struct.pack("<HBQ", v.ndim, _CODES[v.dtype.newbyteorder("<")],
                              head_size + len(body))
        header += struct.pack("<" + "Q" * v.ndim, *v.shape)
        body += v.astype(v.dtype.newbyteorder("<"), copy=False).tobytes()
    assert len(header) == head_size
    write_bytes_atomic(path, bytes(header) + bytes(body))


class _Warp:
    """One ``Marginal2D`` table of the plugin: ``data`` ``[*params, rows, cols]`` (float32) on
    the unit square, interpolated bilinearly inside a slice and linearly across the parameter
    grids ``params`` (one array per leading axis). ``normalise``: each slice scaled to integrate
    to 1 and its continuous conditional (per row) and marginal (over rows) CDFs built, in
    float64 and stored in float32 as the plugin stores them, for :meth:`invert`."""

    def __init__(self, data, params, normalise: bool):
        data = np.asarray(data, np.float32)
        self.params = [np.asarray(p, np.float32) for p in params]
        self.rows, self.cols = data.shape[-2:]
        if self.rows < 2 or self.cols < 2:
            raise DataError(f"a table of {self.rows} x {self.cols}: at least 2 x 2 needed")
        slices = data.reshape(-1, self.rows, self.cols)
        if normalise:
            d = slices.astype(np.float64)
            sx, sy = 0.5 / (self.cols - 1), 0.5 / (self.rows - 1)
            cond = np.cumsum(sx * (d[:, :, :-1] + d[:, :, 1:]), axis=2)  # (S, rows, cols-1)
            row_sum = cond[:, :, -1]
            marg = np.cumsum(sy * (row_sum[:, :-1] + row_sum[:, 1:]), axis=1)  # (S, rows-1)
            norm = (1.0 / marg[:, -1]).astype(np.float32)[:, None, None]
            lead = data.shape[:-2]
            self.cond = (cond.astype(np.float32) * norm).reshape(*lead, self.rows, self.cols - 1)
            self.marg = (marg.astype(np.float32) * norm[:, :, 0]).reshape(*lead, self.rows - 1)
            slices = slices * norm
        self.data = slices.reshape(data.shape)

    def _weights(self, values):
        """Per parameter: the lower grid index and the two weights (Mitsuba's
        ``interpolate_weights``: the interval found by bisection, clamped, weight clipped)."""
        out = []
        for grid, v in zip(self.params, values, strict=True):
            if grid.size == 1:
                out.append((np.zeros(v.shape, int), np.ones(v.shape), np.zeros(v.shape)))
                continue
            idx = np.clip(np.searchsorted(grid, v, side="left") - 1, 0, grid.size - 2)
            p0, p1 = grid[idx].astype(np.float64), grid[idx + 1].astype(np.float64)
            w1 = np.clip((v - p0) / (p1 - p0), 0.0, 1.0)
            out.append((idx, 1.0 - w1, w1))
        return out

    def _corners(self, table, weights, trailing):
        """``table[*params, *trailing]`` interpolated over the parameters: the sum over the
        2^P corners of the parameter cell of weight products times the entries."""
        total = 0.0
        n = len(weights)
        for corner in range(1 << n):
            w = 1.0
            index = []
            for dim, (idx, w0, w1) in enumerate(weights):
                up = (corner >> dim) & 1
                w = w * (w1 if up else w0)
                index.append(np.minimum(idx + up, self.params[dim].size - 1))
            total = total + w * table[(*index, *trailing)].astype(np.float64)
        return total

    def eval(self, pos, values):
        """The bilinear interpolant at ``pos`` (``(x, y)`` in the unit square: x the columns)."""
        weights = self._weights(values)
        x, y, ix, iy, v00, v10, v01, v11 = self._patch(pos, weights)
        return (1 - y) * ((1 - x) * v00 + x * v10) + y * ((1 - x) * v01 + x * v11)

    def _patch(self, pos, weights):
        """The bilinear patch holding ``pos``: the offsets ``x, y`` inside it, its lower
        indices ``ix, iy`` and its corner values ``v00, v10, v01, v11`` (``v10``: one column
        on), interpolated over the parameters."""
        x, y, ix, iy = self._cell(pos)
        corners = [self._corners(self.data, weights, (iy + dy, ix + dx))
                   for dy, dx in ((0, 0), (0, 1), (1, 0), (1, 1))]
        return (x, y, ix, iy, *corners)

    def _cell(self, pos):
        x = np.clip(pos[0], 0.0, 1.0) * (self.cols - 1)
        y = np.clip(pos[1], 0.0, 1.0) * (self.rows - 1)
        ix = np.minimum(x.astype(int), self.cols - 2)
        iy = np.minimum(y.astype(int), self.rows - 2)
        return x - ix, y - iy, ix, iy

    def invert(self, pos, values):
        """The point of the unit square that the continuous warp maps to ``pos``: the
        conditional CDF along the row, then the marginal CDF over rows (``invert_continuous``)."""
        weights = self._weights(values)
        x, y, ix, iy, v00, v10, v01, v11 = self._patch(pos, weights)
        c0 = v00 + (v01 - v00) * y
        c1 = v10 + (v11 - v10) * y
        wx, wy = 1.0 / (self.cols - 1), 1.0 / (self.rows - 1)
        sx = x * (c0 + (c1 - c0) * 0.5 * x) * wx
        before = np.maximum(ix - 1, 0)
        prev0 = self._corners(self.cond, weights, (iy, before))
        prev1 = self._corners(self.cond, weights, (iy + 1, before))
        sx = sx + np.where(ix > 0, prev0 + (prev1 - prev0) * y, 0.0)
        r0 = self._corners(self.cond, weights, (iy, self.cols - 2))
        r1 = self._corners(self.cond, weights, (iy + 1, self.cols - 2))
        sx = sx / (r0 + (r1 - r0) * y)
        sy = y * (r0 + (r1 - r0) * 0.5 * y) * wy
        below = self._corners(self.marg, weights, (np.maximum(iy - 1, 0),))
        sy = sy + np.where(iy > 0, below, 0.0)
        return sx, sy


class RGLMaterial:
    """One RGL ``.bsdf`` material (module docstring), evaluable at any pairs of directions."""

    def __init__(self, fields: dict[str, np.ndarray], name: str = "material"):
        self.name = name
        need = ("theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", "jacobian")
        missing = [k for k in need if k not in fields]
        spectral = "wavelengths" in fields
        table = "spectra" if spectral else "rgb"
        if table not in fields:
            missing.append(table)
        if missing:
            raise DataError(f"{name}: not an RGL material: no field {', '.join(missing)}")
        theta_i = np.asarray(fields["theta_i"], np.float32).reshape(-1)
        phi_i = np.asarray(fields["phi_i"], np.float32).reshape(-1)
        vndf, spectra = fields["vndf"], fields[table]
        nc = len(fields["wavelengths"]) if spectral else 3
        ok = (fields["ndf"].ndim == 2 and fields["sigma"].ndim == 2 and vndf.ndim == 4
              and vndf.shape[:2] == (phi_i.size, theta_i.size) and spectra.ndim == 5
              and spectra.shape[:3] == (phi_i.size, theta_i.size, nc))
        if not ok:
            raise DataError(f"{name}: inconsistent RGL tables (vndf {vndf.shape}, {table} "
                            f"{spectra.shape}, theta_i {theta_i.size}, phi_i {phi_i.size})")
        #: the incident directions the tables were measured at (radians)
        self.theta_i, self.phi_i = theta_i, phi_i
        self.description = bytes(np.asarray(fields.get("description", []), np.uint8)).decode(
            "utf-8", errors="replace")
        self.isotropic = phi_i.size <= 2
        self.reduction = (0 if self.isotropic else
                          int(np.rint(2 * np.pi / float(phi_i[-1] - phi_i[0]))))
        self.jacobian = bool(np.asarray(fields["jacobian"]).reshape(-1)[0])
        self.channels = (tuple(f"{float(w):g}nm" for w in fields["wavelengths"]) if spectral
                         else ("R", "G", "B"))
        self._ndf = _Warp(fields["ndf"], [], normalise=False)
        self._sigma = _Warp(fields["sigma"], [], normalise=False)
        self._vndf = _Warp(vndf, [phi_i, theta_i], normalise=True)
        self._spectra = _Warp(spectra, [phi_i, theta_i, np.arange(nc, dtype=np.float32)],
                              normalise=False)

    def eval_cos(self, wi, wo) -> np.ndarray:
        """``(n, C)``: the plugin's value, the BRDF times ``wo.z`` (0 below the surface)."""
        wi = np.array(wi, np.float64, ndmin=2)
        wo = np.array(wo, np.float64, ndmin=2)
        active = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        if self.reduction >= 2:
            sy = wi[:, 1].copy()
            sx = wi[:, 0].copy() if self.reduction == 4 else sy
            for d in (wi, wo):
                d[:, 0] = np.where(sx >= 0, -d[:, 0], d[:, 0])
                d[:, 1] = np.where(sy >= 0, -d[:, 1], d[:, 1])
        m = wi + wo
        m /= np.maximum(np.linalg.norm(m, axis=1, keepdims=True), np.finfo(float).tiny)
        theta_i, phi_i = _elevation(wi), np.arctan2(wi[:, 1], wi[:, 0])
        theta_m, phi_m = _elevation(m), np.arctan2(m[:, 1], m[:, 0])
        u_wi = (_theta2u(theta_i), _phi2u(phi_i))
        um_y = _phi2u(phi_m - phi_i if self.isotropic else phi_m)
        u_m = (_theta2u(theta_m), um_y - np.floor(um_y))
        sample = self._vndf.invert(u_m, (phi_i, theta_i))
        out = np.stack([self._spectra.eval(sample, (phi_i, theta_i, np.full_like(phi_i, c)))
                        for c in range(len(self.channels))], axis=1)
        if self.jacobian:
            out *= (self._ndf.eval(u_m, ()) / (4.0 * self._sigma.eval(u_wi, ())))[:, None]
        return np.where(active[:, None], out, 0.0)

    def eval(self, wi, wo) -> np.ndarray:
        """``(n, C)``: the BRDF ``f(wi, wo)`` in 1/sr (:meth:`eval_cos` over ``wo.z``)."""
        wo = np.array(wo, np.float64, ndmin=2)
        v = self.eval_cos(wi, wo)
        return np.where(wo[:, 2:3] > 0, v / np.where(wo[:, 2:3] > 0, wo[:, 2:3], 1.0), 0.0)


def _elevation(d):
    """The zenith angle as the plugin computes it, ``2 asin(|d - z| / 2)`` (stable near 0)."""
    dist = np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + (d[:, 2] - 1.0) ** 2)
    return 2.0 * np.arcsin(np.clip(0.5 * dist, 0.0, 1.0))


def _theta2u(theta):
    return np.sqrt(theta * (2.0 / np.pi))


def _phi2u(phi):
    return (phi + np.pi) / (2.0 * np.pi)


#: outgoing zenith angles (degrees) of :func:`default_directions`: 2.5 to 87.5 in steps of 5
DEFAULT_THETA_O_DEG = np.arange(2.5, 90.0, 5.0)
#: outgoing azimuths (degrees) of :func:`default_directions`: 0 to 350 in steps of 10
DEFAULT_PHI_O_DEG = np.arange(0.0, 360.0, 10.0)


def default_directions(material: RGLMaterial) -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)``: every incident direction the file was measured at (its ``theta_i`` grid,
    at each of its ``phi_i``; azimuth 0 for an isotropic material) against outgoing directions
    on a regular grid (:data:`DEFAULT_THETA_O_DEG` x :data:`DEFAULT_PHI_O_DEG`): what
    :func:`read_rgl` reads without directions given."""
    theta_i = material.theta_i.astype(np.float64)
    phi_i = [0.0] if material.isotropic else material.phi_i.astype(np.float64)
    inc = [(t, p) for p in phi_i for t in theta_i if t < np.radians(89.0)]
    to, po = np.meshgrid(np.radians(DEFAULT_THETA_O_DEG), np.radians(DEFAULT_PHI_O_DEG),
                         indexing="ij")
    out = _vec(to.ravel(), po.ravel())
    wi = np.concatenate([np.broadcast_to(_vec(np.array([t]), np.array([p])), out.shape)
                         for t, p in inc])
    return wi, np.tile(out, (len(inc), 1))


def _vec(theta, phi):
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], -1)


def read_rgl(path, wi=None, wo=None) -> GonioData:
    """:class:`~brdf_fit.data.GonioData` of an RGL ``.bsdf`` file at the pairs ``wi``, ``wo``
    (``(n, 3)``; both None: :func:`default_directions`): the BRDF in 1/sr per channel (R, G,
    B, or one per wavelength of a spectral file)."""
    name = os.fspath(path)
    material = RGLMaterial(read_tensor_file(name), name)
    if (wi is None) != (wo is None):
        raise DataError(f"{name}: give both wi and wo, or neither")
    if wi is None:
        wi, wo = default_directions(material)
    value = material.eval(wi, wo)
    return GonioData(wi=wi, wo=wo, value=value, channels=material.channels,
                     metadata={"source": name, "format": "rgl",
                               "description": material.description,
                               "isotropic": material.isotropic})
