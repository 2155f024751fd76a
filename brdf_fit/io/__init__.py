"""Measured-data formats: gonioreflectometer CSV, MERL binary, RGL-EPFL ``.bsdf`` (read at
chosen directions, :mod:`brdf_fit.io.rgl`), npz with a JSON sidecar; and the
Wavefront MTL material reader (:mod:`brdf_fit.io.mtl`: materials, not GonioData, so not in
:func:`read`).

Every reader returns validated :class:`~brdf_fit.data.GonioData` (BRDF in 1/sr, unit vectors in
the local frame) and raises :class:`~brdf_fit.data.DataError` naming the file and the problem.
:func:`read` and :func:`write` pick the format by the file's extension.
"""

from __future__ import annotations

import os
import pathlib

from brdf_fit.data import DataError, GonioData
from brdf_fit.io.csv import read_csv, write_csv
from brdf_fit.io.merl import merl_lookup, read_merl, read_merl_table, write_merl
from brdf_fit.io.mtl import MtlError, MtlMaterial, MtlReadResult, parse_mtl, read_mtl
from brdf_fit.io.npz import read_npz, write_npz
from brdf_fit.io.rgl import read_rgl

__all__ = ["read", "write", "read_csv", "write_csv", "read_merl", "read_merl_table",
           "merl_lookup", "write_merl", "read_npz", "read_rgl", "write_npz", "READ_FORMATS",
           "WRITE_FORMATS", "read_mtl", "parse_mtl", "MtlError", "MtlMaterial", "MtlReadResult"]

#: extension -> reader; ``.json`` is the sidecar of an ``.npz`` file
READ_FORMATS = {".csv": read_csv, ".npz": read_npz, ".json": read_npz, ".binary": read_merl,
                ".bsdf": read_rgl}
#: extensions :func:`write` accepts
WRITE_FORMATS = (".csv", ".npz")


def _ext(path) -> str:
    return pathlib.Path(path).suffix.lower()


def read(path) -> GonioData:
    """:class:`~brdf_fit.data.GonioData` from ``.csv``, ``.npz`` (or its ``.json`` sidecar), a
    MERL ``.binary`` file or an RGL ``.bsdf`` file (at :func:`brdf_fit.io.rgl.
    default_directions`), chosen by the extension. Raises :class:`~brdf_fit.data.DataError`
    naming the file for an unknown extension, a missing file or bad content."""
    ext = _ext(path)
    if ext not in READ_FORMATS:
        raise DataError(f"{path}: unknown data format {ext or '(no extension)'!r}; expected .csv, "
                        ".npz (with its .json sidecar), a MERL .binary or an RGL .bsdf")
    if not os.path.exists(path):
        raise DataError(f"{path}: no such file")
    return READ_FORMATS[ext](path)


def check_writable_format(path) -> None:
    """Raise :class:`~brdf_fit.data.DataError` if :func:`write` cannot write this extension (so
    a caller can refuse a bad output path before any work)."""
    ext = _ext(path)
    if ext == ".binary":
        raise DataError(f"{path}: a MERL .binary file is a full half/difference-angle table, not "
                        "scattered samples; write .csv or .npz (brdf_fit.io.write_merl tabulates "
                        "a model)")
    if ext not in WRITE_FORMATS:
        raise DataError(f"{path}: unknown output format {ext or '(no extension)'!r}; expected "
                        ".csv or .npz")


def write(data: GonioData, path, provenance: dict | None = None) -> list[str]:
    """Write ``data`` by the extension of ``path`` (``.csv``, or ``.npz`` with a ``.json``
    sidecar holding ``provenance``); returns the paths written. An unknown extension or an
    unwritable path raises :class:`~brdf_fit.data.DataError`."""
    check_writable_format(path)
    try:
        if _ext(path) == ".csv":
            write_csv(data, path)
            return [str(path)]
        return list(write_npz(data, path, provenance=provenance))
    except OSError as e:
        raise DataError(f"{path}: cannot write ({e.strerror or e})") from None
