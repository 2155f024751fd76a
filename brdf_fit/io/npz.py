"""GonioData as ``.npz`` arrays plus a JSON sidecar.

``write_npz(data, "scan.npz")`` writes two files:

``scan.npz``   the arrays ``wi``, ``wo`` (N, 3), ``value``, ``weight`` (N, C) and, if present,
               ``sigma`` (N, C), all float64 (``numpy.savez_compressed``, no pickles)
``scan.json``  the sidecar: ``schema`` (``"brdf_fit.gonio"``), ``schema_version``
               (:data:`SCHEMA_VERSION`), ``channels``, ``n``, ``units``, the data's ``metadata``,
               ``provenance`` (the writing library's version plus whatever the caller passes) and
               ``arrays``: name -> shape and the SHA-256 of the ``.npz`` file, so a sidecar that
               no longer matches its arrays is detected.

The output is deterministic: no time stamps unless the caller puts one in ``provenance``.
:func:`read_npz` accepts either file's path, checks the schema, version, checksum, array names
and shapes, validates the data (:meth:`GonioData.validate`) and raises
:class:`~brdf_fit.data.DataError` naming the file and the problem.
"""

from __future__ import annotations

import hashlib
import json
import os
import pathlib
import zipfile

import numpy as np

from brdf_fit._version import __version__
from brdf_fit.core.atomic import atomic_path, write_text_atomic
from brdf_fit.core.limits import LimitError, check_bytes
from brdf_fit.data import DataError, GonioData

__all__ = ["SCHEMA", "SCHEMA_VERSION", "write_npz", "read_npz", "sidecar_path"]

SCHEMA = "brdf_fit.gonio"
#: Bump when the layout changes; readers refuse newer versions than they know.
SCHEMA_VERSION = 1
_REQUIRED = ("wi", "wo", "value", "weight")
_UNITS = {"wi": "unit vector, local frame (z = normal), pointing away from the surface",
          "wo": "unit vector, local frame (z = normal), pointing away from the surface",
          "value": "BRDF in 1/sr (not multiplied by cos)", "sigma": "1/sr",
          "weight": "dimensionless (0 masks a sample)"}


def _paths(path) -> tuple[pathlib.Path, pathlib.Path]:
    p = pathlib.Path(os.fspath(path))
    if p.suffix in (".npz", ".json"):
        p = p.with_suffix("")
    return p.with_suffix(".npz"), p.with_suffix(".json")


def sidecar_path(path) -> pathlib.Path:
    """The JSON sidecar that belongs to ``path`` (``x.npz`` -> ``x.json``)."""
    return _paths(path)[1]


def _jsonable(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, pathlib.PurePath):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _sha256(path: pathlib.Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_npz(data: GonioData, path, provenance: dict | None = None) -> tuple[str, str]:
    """Write ``data`` as ``<stem>.npz`` plus ``<stem>.json`` (see the module docstring).
    ``provenance``: extra JSON-able fields (recipe, instrument, command line). Returns the two
    paths."""
    npz, side = _paths(path)

    try:
        metadata = json.loads(json.dumps(data.metadata, default=_jsonable))
        prov = {"library": "brdf_fit", "version": __version__,
                **json.loads(json.dumps(provenance or {}, default=_jsonable))}
    except (TypeError, ValueError) as e:
        raise DataError(f"write_npz: metadata/provenance must be JSON serialisable ({e})") from None
    arrays = {"wi": data.wi, "wo": data.wo, "value": data.value, "weight": data.weight}
    if data.sigma is not None:
        arrays["sigma"] = data.sigma
    arrays = {k: np.ascontiguousarray(v, dtype="<f8") for k, v in arrays.items()}
    with atomic_path(npz) as tmp:  # (its name ends in .npz: numpy adds no suffix)
        np.savez_compressed(tmp, **arrays)
    doc = {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "n": data.n,
        "channels": list(data.channels),
        "arrays": {k: list(v.shape) for k, v in arrays.items()},
        "npz_file": npz.name,
        "npz_sha256": _sha256(npz),
        "units": {k: _UNITS[k] for k in arrays},
        "metadata": metadata,
        "provenance": prov,
    }
    write_text_atomic(side, json.dumps(doc, indent=2, sort_keys=True) + "\n")
    return str(npz), str(side)


#: bytes a member's stored size may exceed its array's (the .npy header: 64-byte aligned, at
#: most a few hundred bytes for these arrays; numpy.lib.format)
_HEADER_SLACK = 4096


def _check_members(npz: pathlib.Path, expect: dict) -> None:
    """Refuse a ``.npz`` whose members are not this format's arrays, before decompressing any:
    every member named in ``expect`` (an unknown one is reported by name: a 4 GiB member of
    zeros went through unread, and decompressed, before), its ``.npy`` header read from the
    first bytes of its stream (a float array of the sidecar's shape, no objects), its stored
    size within the header's plus :data:`_HEADER_SLACK` (the decompressed size is then
    bounded), and the arrays' total against the memory limit (:mod:`brdf_fit.core.limits`)."""
    try:
        zf = zipfile.ZipFile(npz)
    except (OSError, zipfile.BadZipFile, ValueError) as e:
        raise DataError(f"{npz}: not a readable .npz file (not a zip archive: {e})") from None
    total = 0
    with zf:
        infos = zf.infolist()
        names = [i.filename[:-4] if i.filename.endswith(".npy") else i.filename for i in infos]
        unknown = sorted(set(names) - set(expect))
        if unknown:
            raise DataError(f"{npz}: unknown member(s) {unknown}; a {SCHEMA} .npz holds only "
                            f"{', '.join(expect)}")
        for info, name in zip(infos, names, strict=True):
            try:
                with zf.open(info) as fh:
                    major, _ = np.lib.format.read_magic(fh)
                    read = (np.lib.format.read_array_header_1_0 if major == 1
                            else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read(fh)
            except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
                raise DataError(f"{npz}: member {name!r} is not a .npy array ({e})") from None
            if dtype.hasobject or dtype.kind != "f":
                raise DataError(f"{npz}: array {name!r} has dtype {dtype}, expected float")
            if tuple(shape) != expect[name]:
                raise DataError(f"{npz}: array {name!r} has shape {tuple(shape)}, the sidecar "
                                f"says {expect[name]}")
            nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            if info.file_size > nbytes + _HEADER_SLACK:
                raise DataError(f"{npz}: member {name!r} stores {info.file_size:,} bytes for a "
                                f"{nbytes:,}-byte array; the file is damaged or not this "
                                "format")
            total += nbytes
    try:
        check_bytes(total, f"{npz}: its arrays")
    except LimitError as e:
        raise DataError(str(e)) from None


def read_npz(path, validate: bool = True) -> GonioData:
    """Read a dataset written by :func:`write_npz` (``path``: the ``.npz`` or the ``.json``).
    The returned metadata is the stored metadata plus ``provenance``, ``schema_version``,
    ``source`` and ``format``."""
    npz, side = _paths(path)
    try:
        doc = json.loads(side.read_text(encoding="utf-8"))
    except OSError as e:
        raise DataError(f"{side}: cannot read the JSON sidecar of {npz.name} "
                        f"({e.strerror or e})") from None
    except ValueError as e:
        raise DataError(f"{side}: the sidecar is not valid JSON ({e})") from None
    if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
        got = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
        raise DataError(f"{side}: not a {SCHEMA} sidecar (schema = {got!r})")
    version = doc.get("schema_version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise DataError(f"{side}: schema_version must be a positive integer, got {version!r}")
    if version > SCHEMA_VERSION:
        raise DataError(f"{side}: schema_version {version} is newer than this reader "
                        f"({SCHEMA_VERSION}); upgrade brdf_fit")
    for key in ("n", "channels", "arrays"):
        if key not in doc:
            raise DataError(f"{side}: missing field {key!r}")
    try:
        digest = _sha256(npz)
    except OSError as e:
        raise DataError(f"{npz}: cannot read the arrays ({e.strerror or e})") from None
    if doc.get("npz_sha256") not in (None, digest):
        raise DataError(f"{npz}: SHA-256 {digest[:12]}... does not match the sidecar "
                        f"({str(doc['npz_sha256'])[:12]}...); the files do not belong together "
                        "or one was modified")
    n, channels = doc["n"], doc["channels"]
    if not isinstance(n, int) or isinstance(n, bool) or n < 0:
        raise DataError(f"{side}: n must be a non-negative integer, got {n!r}")
    if not isinstance(channels, list) or not channels or not all(
            isinstance(c, str) for c in channels):
        raise DataError(f"{side}: channels must be a non-empty list of names, got {channels!r}")
    channels = tuple(channels)
    expect = {"wi": (n, 3), "wo": (n, 3), "value": (n, len(channels)),
              "weight": (n, len(channels)), "sigma": (n, len(channels))}
    _check_members(npz, expect)  # names, dtypes, shapes and sizes, before any is decompressed
    try:
        with np.load(npz, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile) as e:
        raise DataError(f"{npz}: not a readable .npz file ({e})") from None
    missing = [k for k in _REQUIRED if k not in arrays]
    if missing:
        raise DataError(f"{npz}: missing array(s) {missing}; found {sorted(arrays)}")
    for k, a in arrays.items():
        if k in expect and a.shape != expect[k]:
            raise DataError(f"{npz}: array {k!r} has shape {a.shape}, the sidecar says "
                            f"{expect[k]} (n = {n}, channels = {list(channels)})")
        if k in expect and a.dtype.kind != "f":
            raise DataError(f"{npz}: array {k!r} has dtype {a.dtype}, expected float")
    if not isinstance(doc.get("metadata") or {}, dict):
        raise DataError(f"{side}: metadata must be a JSON object, got "
                        f"{type(doc['metadata']).__name__}")
    metadata = dict(doc.get("metadata") or {})
    metadata.update({"provenance": doc.get("provenance", {}), "schema_version": version,
                     "source": str(npz), "format": "npz"})
    data = GonioData(wi=arrays["wi"], wo=arrays["wo"], value=arrays["value"],
                     weight=arrays["weight"], sigma=arrays.get("sigma"), channels=channels,
                     metadata=metadata)
    if validate:
        try:
            data.validate()
        except DataError as e:
            raise DataError(f"{npz}: {e}") from None
    return data
