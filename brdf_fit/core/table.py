"""Tabulated functions on regular grids, and their differentiable lookup inside JAX.

A :class:`Table` holds values on the tensor product of regular :class:`Axis` grids (one value or
several named channels per node) and a JSON-serialisable metadata dict. :meth:`Table.lookup`
interpolates multilinearly; it is a pure ``jax.numpy`` function of the coordinates and of the
values, so it works under ``jit``, ``vmap`` and ``grad`` (with respect to both), and models of
layer 1 can use a table (e.g. a packaged albedo table) without depending on the code that
computed it (``brdf_fit.tables``, layer 3).

Grid conventions (stated once; every table names its own in ``Axis.centres``):

* **texel centres** (``centres=True``): node ``i`` of ``n`` sits at
  ``lo + (i + 0.5) (hi - lo) / n``, as a GPU texture of ``n`` texels over ``[lo, hi]`` samples it;
  a lookup outside ``[x_0, x_{n-1}]`` returns the edge node's value (``CLAMP_TO_EDGE``).
* **endpoints** (``centres=False``): node ``i`` sits at ``lo + i (hi - lo) / (n - 1)``; a lookup
  outside ``[lo, hi]`` is clamped to the interval.

Interpolation is linear in each axis (bilinear for two, trilinear for three), which is what a GPU
sampler does with ``LINEAR`` filtering; its error for a smooth table is ``h^2/8 max|f''|`` per
axis (``h`` the node spacing), reported by ``brdf_fit.tables`` for each table it builds.
``lookup(..., order=3)`` interpolates by cubic Lagrange polynomials through 4 nodes per axis
instead (error ``O(h^4)``; Kelemen's packaged albedo table uses it).
"""

from __future__ import annotations

import hashlib
import importlib.resources
import itertools
import json
import os
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Axis", "Table", "load_table", "load_packaged_table", "parse_descriptor",
           "values_sha256"]

#: the descriptor tag and the newest version :func:`load_table` reads (the ``.npz`` layout of
#: ``brdf_fit.tables.export``, which writes it)
TABLE_FORMAT = "brdf_fit.table"
TABLE_FORMAT_VERSION = 1


class Axis(eqx.Module):
    """A regular grid on ``[lo, hi]`` with ``n`` nodes at texel centres or at the endpoints."""

    name: str = eqx.field(static=True)
    lo: float = eqx.field(static=True)
    hi: float = eqx.field(static=True)
    n: int = eqx.field(static=True)
    centres: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        if not isinstance(self.n, int) or self.n < 1 or (not self.centres and self.n < 2):
            need = 1 if self.centres else 2
            raise ValueError(f"axis {self.name!r}: need an integer n >= {need}, got {self.n!r}")
        if not (np.isfinite(self.lo) and np.isfinite(self.hi) and self.hi > self.lo):
            raise ValueError(
                f"axis {self.name!r}: need lo < hi (finite), got [{self.lo}, {self.hi}]")

    def nodes(self) -> np.ndarray:
        """The node positions, float64 NumPy, shape ``(n,)``."""
        i = np.arange(self.n, dtype=np.float64)
        if self.centres:
            return self.lo + (i + 0.5) * (self.hi - self.lo) / self.n
        return self.lo + i * (self.hi - self.lo) / (self.n - 1)

    def spacing(self) -> float:
        return (self.hi - self.lo) / (self.n if self.centres else self.n - 1)

    def index(self, x):
        """Continuous node index of ``x`` (``jax.numpy``), clamped to ``[0, n - 1]``."""
        t = (x - self.lo) / self.spacing() - (0.5 if self.centres else 0.0)
        return jnp.clip(t, 0.0, self.n - 1.0)

    def to_dict(self) -> dict:
        return {"name": self.name, "lo": self.lo, "hi": self.hi, "n": self.n,
                "centres": self.centres}

    @classmethod
    def from_dict(cls, d: Mapping) -> Axis:
        return cls(str(d["name"]), float(d["lo"]), float(d["hi"]), int(d["n"]),
                   bool(d.get("centres", True)))


class Table(eqx.Module):
    """Values on a regular grid: ``values`` has shape ``(axes[0].n, ..., axes[-1].n, C)`` with
    ``C = len(channels)``; ``meta`` is a JSON-serialisable dict (kept as a JSON string so that a
    table is a hashable static structure plus one array leaf)."""

    values: jax.Array
    axes: tuple[Axis, ...] = eqx.field(static=True)
    channels: tuple[str, ...] = eqx.field(static=True)
    meta_json: str = eqx.field(static=True, default="{}")

    def __init__(self, values, axes: Sequence[Axis], channels: Sequence[str],
                 meta: Mapping | None = None):
        self.axes = tuple(axes)
        self.channels = tuple(str(c) for c in channels)
        shape = tuple(a.n for a in self.axes) + (len(self.channels),)
        values = values if isinstance(values, jax.Array) else np.asarray(values)
        if values.shape != shape:
            raise ValueError(
                f"table values have shape {values.shape}; axes {[a.name for a in self.axes]} and "
                f"channels {list(self.channels)} need {shape}"
            )
        self.values = values
        self.meta_json = json.dumps(dict(meta or {}), sort_keys=True)

    @property
    def meta(self) -> dict:
        return json.loads(self.meta_json)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.values.shape)

    def axis(self, name: str) -> Axis:
        for a in self.axes:
            if a.name == name:
                return a
        raise KeyError(f"table has no axis {name!r}; it has {[a.name for a in self.axes]}")

    def channel(self, name: str):
        """The values of one channel, shape ``(axes[0].n, ...)``."""
        try:
            k = self.channels.index(name)
        except ValueError:
            raise KeyError(f"table has no channel {name!r}; it has {list(self.channels)}") from None
        return self.values[..., k]

    def with_meta(self, **extra) -> Table:
        return Table(self.values, self.axes, self.channels, {**self.meta, **extra})

    def lookup(self, *coords, order: int = 1):
        """Interpolation at ``coords`` (one array per axis, in axis order, broadcast together);
        returns shape ``broadcast + (C,)``. Differentiable in the coordinates (inside the grid;
        0 where clamped) and in ``values``.

        ``order=1``: multilinear (a GPU's ``LINEAR`` filtering), error ``h^2/8 max|f''|`` per
        axis. ``order=3``: cubic Lagrange interpolation through the 4 nearest nodes in each axis
        (the stencil ``i-1 .. i+2`` of the cell ``[i, i+1]``, shifted inwards at the ends; axes
        with fewer than 4 nodes stay linear): continuous, error ``3/128 h^4 max|f^(4)|`` at a
        cell's midpoint, for smooth tables needed more finely than a linear grid of reasonable
        size gives."""
        if len(coords) != len(self.axes):
            raise ValueError(f"lookup needs {len(self.axes)} coordinates "
                             f"({[a.name for a in self.axes]}), got {len(coords)}")
        if order not in (1, 3):
            raise ValueError(f"lookup order must be 1 (linear) or 3 (cubic), got {order!r}")
        values = jnp.asarray(self.values)
        coords = jnp.broadcast_arrays(*(jnp.asarray(c, dtype=values.dtype) for c in coords))
        # per axis: the stencil's first node and the weights of its nodes
        starts, weights = [], []
        for ax, c in zip(self.axes, coords, strict=True):
            t = ax.index(c)
            if order == 3 and ax.n >= 4:
                t = jnp.clip(t, 0.0, float(ax.n - 1))
                s0 = jnp.clip(jnp.floor(t) - 1.0, 0.0, float(ax.n - 4))
                u = t - s0  # in [0, 3]: the stencil's nodes sit at 0, 1, 2, 3
                w = [-(u - 1.0) * (u - 2.0) * (u - 3.0) / 6.0, u * (u - 2.0) * (u - 3.0) / 2.0,
                     -u * (u - 1.0) * (u - 3.0) / 2.0, u * (u - 1.0) * (u - 2.0) / 6.0]
            else:
                s0 = jnp.clip(jnp.floor(t), 0.0, float(max(ax.n - 2, 0)))
                f = t - s0 if ax.n > 1 else jnp.zeros_like(t)
                w = [1.0 - f, f]
            starts.append(s0.astype(jnp.int32))
            weights.append(w)
        out = 0.0
        for offsets in itertools.product(*(range(len(w)) for w in weights)):
            idx, wt = [], 1.0
            for k, o in enumerate(offsets):
                idx.append(jnp.minimum(starts[k] + o, self.axes[k].n - 1))
                wt = wt * weights[k][o]
            out = out + wt[..., None] * values[tuple(idx)]
        return out


def parse_descriptor(text: str, where: str) -> dict:
    """The JSON descriptor every table file embeds (``brdf_fit.tables.export``), checked: valid
    JSON, this format, a version this reader knows. ``where`` names the file in errors."""
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{where}: the brdf_fit metadata is not valid JSON ({e})") from None
    if not isinstance(d, dict) or d.get("format") != TABLE_FORMAT:
        raise ValueError(f"{where}: no {TABLE_FORMAT!r} descriptor in the metadata")
    if int(d.get("format_version", 0)) > TABLE_FORMAT_VERSION:
        raise ValueError(f"{where}: format version {d['format_version']} is newer than this "
                         f"reader's ({TABLE_FORMAT_VERSION}); upgrade brdf_fit")
    return d


def values_sha256(values) -> str:
    """SHA-256 of table values as float64, little-endian, C order (identifies the table, not
    the file)."""
    return hashlib.sha256(np.ascontiguousarray(values, dtype="<f8").tobytes()).hexdigest()


def load_table(path: str | os.PathLike, descriptor: str | None = None) -> Table:
    """Read a table from an ``.npz`` file in the layout ``brdf_fit.tables.export.write_table``
    writes (its module docstring): one array per channel named after the channel, and
    ``meta_json``, a 0-d string array holding the descriptor (``axes``, ``channels``, ``meta``,
    ``dtype``, ``sha256`` of the values as little-endian float64); ``descriptor`` (its JSON text,
    e.g. from a sidecar file) replaces a missing ``meta_json``. No pickles are loaded; the values
    are checked against the recorded ``sha256``.

    This is the reader models use for packaged tables (``brdf_fit/resources/tables``): it lives
    here, in layer 0, so that a model can load a table without importing ``brdf_fit.tables``
    (layer 3); ``export.read_table`` uses it for ``.npz``. Raises :class:`ValueError` naming the
    file when it is not such a table."""
    where = os.fspath(path)
    with np.load(path, allow_pickle=False) as z:
        if "meta_json" in z.files:
            descriptor = str(z["meta_json"][()])
        elif descriptor is None:
            raise ValueError(f"{where}: no 'meta_json' array (not a brdf_fit .npz table)")
        d = parse_descriptor(descriptor, where)
        missing = [c for c in d["channels"] if c not in z.files]
        if missing:
            raise ValueError(f"{where}: channel arrays {missing} are missing")
        values = np.stack([z[c] for c in d["channels"]], axis=-1)
    if "dtype" in d and values.dtype != np.dtype(d["dtype"]):
        raise ValueError(f"{where}: arrays are {values.dtype}, the descriptor says {d['dtype']}")
    if d.get("sha256") and values_sha256(values) != d["sha256"]:
        raise ValueError(f"{where}: the values do not match the recorded sha256 (file altered?)")
    axes = [Axis.from_dict(a) for a in d["axes"]]
    shape = tuple(a.n for a in axes) + (len(d["channels"]),)
    if values.shape != shape:
        raise ValueError(f"{where}: the data have shape {values.shape}, the metadata says {shape}")
    return Table(values, axes, d["channels"], d.get("meta") or {})


def load_packaged_table(name: str) -> Table:
    """The table ``name`` the package ships in ``brdf_fit/resources/tables`` (package data, read
    through :mod:`importlib.resources`), by :func:`load_table`. Not cached: each model keeps the
    tables it uses (in the dtypes it evaluates in)."""
    ref = importlib.resources.files("brdf_fit") / "resources" / "tables" / name
    with importlib.resources.as_file(ref) as p:
        return load_table(p)
