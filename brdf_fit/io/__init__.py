"""Measured-data formats: gonioreflectometer CSV, MERL binary, npz with a JSON sidecar.

Every reader returns validated :class:`~brdf_fit.data.GonioData` (BRDF in 1/sr, unit vectors in
the local frame) and raises :class:`~brdf_fit.data.DataError` naming the file and the problem.
"""

from .csv import read_csv, write_csv
from .merl import merl_lookup, read_merl, read_merl_table, write_merl
from .npz import read_npz, write_npz

__all__ = ["read_csv", "write_csv", "read_merl", "read_merl_table", "merl_lookup", "write_merl",
           "read_npz", "write_npz"]
