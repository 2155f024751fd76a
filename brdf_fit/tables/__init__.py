"""Lookup tables (layer 3): generate, store and read tables of BRDF integrals.

``dfg_table`` (split-sum ``A``, ``B`` of GGX, :mod:`brdf_fit.tables.dfg`), ``ms_tables`` (the
energy-compensation ``E``, ``E_avg`` of GGX that ``brdf_fit/resources/tables`` ships,
:mod:`brdf_fit.tables.energy`; Kelemen's specular-albedo table, :mod:`brdf_fit.tables.kelemen`),
the layouts engines use (:mod:`brdf_fit.tables.layouts`), and ``write_table`` / ``read_table``
for ``.npz``, OpenEXR, 16-bit PNG and C/GLSL headers (:mod:`brdf_fit.tables.export`). The table
object and its differentiable ``lookup`` live in :mod:`brdf_fit.core.table` (layer 0), so models
can use tables.
"""

from brdf_fit.core.table import Axis, Table
from brdf_fit.tables.dfg import DFG_MASKINGS, dfg_table, dfg_values
from brdf_fit.tables.energy import ms_tables
from brdf_fit.tables.export import check_output, read_table, write_table
from brdf_fit.tables.layouts import LAYOUTS, Layout, resolve_layout

__all__ = ["DFG_MASKINGS", "LAYOUTS", "Axis", "Layout", "Table", "check_output", "dfg_table",
           "dfg_values", "ms_tables", "read_table", "resolve_layout", "write_table"]
