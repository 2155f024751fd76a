"""Gonioreflectometer CSV files: one row per sample.

Format
------
* Lines starting with ``#`` are comments. ``# key: value`` comments become metadata (values are
  parsed as JSON when possible, else kept as text). The key ``quantity`` is special (see below).
  Blank lines are skipped.
* The first other line is the header. The delimiter is ``,`` (or tab / ``;`` / whitespace, detected
  from the header). Column names are case-insensitive.
* Angle columns ``theta_i, phi_i, theta_o, phi_o`` in **degrees** (``theta_r, phi_r`` are accepted
  for the outgoing pair). A ``_rad`` suffix (``theta_i_rad``) marks radians, ``_deg`` degrees;
  ``angles="rad"`` makes unsuffixed columns radians. ``theta`` must lie in [0, 90] deg; ``phi`` is
  absolute (measured from the tangent x axis) in [-360, 360] deg, so the in-plane specular
  direction is ``phi_o = phi_i + 180``.
* Value columns, one family per file: ``<q>`` (one channel, named ``"Y"``), ``<q>_r, <q>_g, <q>_b``
  (channels ``R, G, B``), ``<q>_<nm>nm`` (spectral, channels ``"550nm"``...), or ``<q>_<name>``.
  The family name ``<q>`` declares the quantity and the reader converts it to BRDF in 1/sr:

  ============  ==========================  ===========================
  family        file holds                  BRDF [1/sr] =
  ============  ==========================  ===========================
  ``brdf``      BRDF in 1/sr                value
  ``brf``       reflectance factor          value / pi
  ``brdfcos``   BRDF * cos(theta_o)         value / cos(theta_o)
  ``value``     declared by ``# quantity:`` (or ``quantity=``), default ``brdf``
  ============  ==========================  ===========================

  A ``# quantity: X`` comment or ``quantity=`` argument that contradicts a named family is an
  error. ``sigma`` columns (same suffixes) are in the same quantity as the values and are
  converted with them. ``weight`` (one column for all channels) or ``weight_<suffix>`` columns
  are optional (default 1; 0 masks a sample, e.g. one below the horizon).
* Other columns are ignored.

Every problem raises :class:`~brdf_fit.data.DataError` naming the file, the 1-based line number
and the column.
"""

from __future__ import annotations

import json
import math
import os
import re

import numpy as np

from brdf_fit.core.atomic import write_text_atomic
from brdf_fit.data import DataError, GonioData, channel_wavelengths

__all__ = ["read_csv", "write_csv", "QUANTITIES"]

#: Quantity name -> human description. Conversion to BRDF in :func:`_to_brdf`.
QUANTITIES = {
    "brdf": "BRDF in 1/sr",
    "brf": "reflectance factor BRF = pi * BRDF",
    "brdfcos": "BRDF * cos(theta_o) in 1/sr",
}
_FAMILY = re.compile(r"^(brdfcos|brdf|brf|value|sigma|weight)(?:_(.+))?$")
_ANGLE = re.compile(r"^(theta|phi)_(i|o|r)(?:_(deg|rad))?$")
_NM = re.compile(r"^([0-9]+(?:\.[0-9]*)?)\s*nm$")
_META = re.compile(r"^#\s*([A-Za-z_][\w.\-]*)\s*:\s*(.*?)\s*$")


def _err(path, msg, line=None, column=None):
    where = str(path)
    if line is not None:
        where += f", line {line}"
    if column is not None:
        where += f", column {column!r}"
    return DataError(f"{where}: {msg}")


def _channel_from_suffix(suffix: str | None) -> str:
    if suffix is None:
        return "Y"
    m = _NM.match(suffix)
    if m:
        return f"{float(m.group(1)):g}nm"
    if suffix in ("r", "g", "b", "y"):
        return suffix.upper()
    return suffix


def _suffix_from_channel(channel: str, n_channels: int) -> str:
    if n_channels == 1 and channel == "Y":
        return ""
    if channel in ("R", "G", "B", "Y"):
        return "_" + channel.lower()
    return "_" + channel


def _parse_meta_value(text: str):
    try:
        return json.loads(text)
    except ValueError:
        return text


def _split(line: str, delim: str | None) -> list[str]:
    return [c.strip() for c in (line.split(delim) if delim else line.split())]


def _to_brdf(quantity: str, arr: np.ndarray, cos_o: np.ndarray) -> np.ndarray:
    if quantity == "brdf":
        return arr
    if quantity == "brf":
        return arr / np.pi
    # brdfcos; rows with cos_o <= 0 are masked (weight 0) by the time this runs
    safe = np.where(cos_o > 0.0, cos_o, 1.0)
    return np.where(cos_o[:, None] > 0.0, arr / safe[:, None], 0.0)


def read_csv(path, angles: str = "deg", quantity: str | None = None,
             allow_negative_sigmas: float = 5.0) -> GonioData:
    """Read a gonioreflectometer CSV file (format in the module docstring) into validated
    :class:`GonioData` with BRDF values in 1/sr.

    ``angles``: unit of angle columns without a ``_deg``/``_rad`` suffix (``"deg"`` or ``"rad"``).
    ``quantity``: what ``value*`` columns hold (``"brdf"``, ``"brf"``, ``"brdfcos"``); overrides a
    ``# quantity:`` comment and must agree with a named column family.
    """
    if angles not in ("deg", "rad"):
        raise ValueError(f"angles must be 'deg' or 'rad', got {angles!r}")
    if quantity is not None and quantity.lower() not in QUANTITIES:
        raise ValueError(f"quantity must be one of {sorted(QUANTITIES)}, got {quantity!r}")
    name = os.fspath(path)
    try:
        with open(name, encoding="utf-8-sig") as fh:
            lines = fh.read().splitlines()
    except OSError as e:
        raise DataError(f"{name}: cannot read CSV file ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise DataError(f"{name}: not a UTF-8 text file (is it a binary format?)") from None

    metadata: dict = {}
    header: list[str] | None = None
    header_line = 0
    delim: str | None = None
    rows: list[list[str]] = []
    row_lines: list[int] = []
    for lineno, raw in enumerate(lines, start=1):
        s = raw.strip()
        if not s:
            continue
        if s.startswith("#"):
            m = _META.match(s)
            if m:
                metadata[m.group(1)] = _parse_meta_value(m.group(2))
            continue
        if header is None:
            delim = next((d for d in (",", "\t", ";") if d in s), None)
            header = [c.lower() for c in _split(s, delim)]
            header_line = lineno
            continue
        cells = _split(s, delim)
        if len(cells) != len(header):
            raise _err(name, f"{len(cells)} cells, but the header (line {header_line}) has "
                             f"{len(header)} columns", line=lineno)
        rows.append(cells)
        row_lines.append(lineno)
    if header is None:
        raise DataError(f"{name}: no header row (the file is empty or only comments)")
    if not rows:
        raise DataError(f"{name}: no data rows after the header (line {header_line})")
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise _err(name, f"duplicate column(s) {dup}", line=header_line)

    # ---------------------------------------------------------------- columns
    angle_cols: dict[tuple[str, str], tuple[int, str, bool]] = {}
    families: dict[str, dict[str, tuple[int, str]]] = {}
    for j, col in enumerate(header):
        m = _ANGLE.match(col)
        if m:
            kind, side, unit = m.group(1), "o" if m.group(2) == "r" else m.group(2), m.group(3)
            if (kind, side) in angle_cols:
                other = header[angle_cols[(kind, side)][0]]
                raise _err(name, f"columns {other!r} and {col!r} give the same angle",
                           line=header_line)
            angle_cols[(kind, side)] = (j, col, (unit or angles) == "rad")
            continue
        m = _FAMILY.match(col)
        if m:
            fam = families.setdefault(m.group(1), {})
            fam[_channel_from_suffix(m.group(2))] = (j, col)
    for kind, side in (("theta", "i"), ("phi", "i"), ("theta", "o"), ("phi", "o")):
        if (kind, side) not in angle_cols:
            raise _err(name, f"missing column {kind}_{side!s} (or {kind}_{side}_rad); header is "
                             f"{header}", line=header_line)
    value_fams = [f for f in ("brdf", "brf", "brdfcos", "value") if f in families]
    if not value_fams:
        raise _err(name, "missing value column(s): expected brdf, brdf_r/_g/_b, brdf_<nm>nm "
                         f"(or the brf / brdfcos / value families); header is {header}",
                   line=header_line)
    if len(value_fams) > 1:
        raise _err(name, f"value columns from several families {value_fams}; use one",
                   line=header_line)
    fam = value_fams[0]
    declared = quantity.lower() if quantity is not None else None
    if declared is None and "quantity" in metadata:
        declared = str(metadata["quantity"]).strip().lower()
        if declared not in QUANTITIES:
            raise _err(name, f"unknown '# quantity: {metadata['quantity']}'; expected one of "
                             f"{sorted(QUANTITIES)}")
    if fam == "value":
        qty = declared or "brdf"
    else:
        qty = fam
        if declared is not None and declared != fam:
            raise _err(name, f"declared quantity {declared!r} contradicts the {fam!r} value "
                             "columns", line=header_line)
    chan_cols = families[fam]
    channels = tuple(chan_cols)
    if "Y" in chan_cols and len(chan_cols) > 1:
        raise _err(name, f"both an unsuffixed {fam!r} column and per-channel columns",
                   line=header_line)
    if channel_wavelengths(channels) is not None:
        channels = tuple(sorted(channels, key=lambda c: float(c[:-2])))
    for aux in ("sigma", "weight"):
        if aux not in families:
            continue
        extra = set(families[aux]) - set(channels) - {"Y"}
        if extra:
            cols = [families[aux][c][1] for c in sorted(extra)]
            raise _err(name, f"{aux} column(s) {cols} match no value channel {channels}",
                       line=header_line)
        missing = [c for c in channels if c not in families[aux] and "Y" not in families[aux]]
        if missing:
            raise _err(name, f"{aux} columns are missing for channel(s) {missing}",
                       line=header_line)

    # ---------------------------------------------------------------- numbers
    def column(j: int, col: str) -> np.ndarray:
        out = np.empty(len(rows))
        for r, cells in enumerate(rows):
            cell = cells[j]
            try:
                v = float(cell)
            except ValueError:
                what = "empty cell" if cell == "" else f"non-numeric cell {cell!r}"
                raise _err(name, what, line=row_lines[r], column=col) from None
            if not math.isfinite(v):
                raise _err(name, f"{cell!r} is not a finite number", line=row_lines[r],
                           column=col)
            out[r] = v
        return out

    ang = {}
    for (kind, side), (j, col, is_rad) in angle_cols.items():
        a = column(j, col)
        lo, hi = (0.0, 90.0) if kind == "theta" else (-360.0, 360.0)
        a_deg = np.degrees(a) if is_rad else a
        tol = 1e-9 * max(abs(hi), 1.0)
        bad = (a_deg < lo - tol) | (a_deg > hi + tol)
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            unit = "rad" if is_rad else "deg"
            rng = (f"[{np.radians(lo):g}, {np.radians(hi):.6g}] rad" if is_rad
                   else f"[{lo:g}, {hi:g}] deg")
            below = " (below the horizon)" if kind == "theta" and a_deg[r] > hi else ""
            raise _err(name, f"{kind} = {a[r]:g} {unit} is out of range {rng}{below}",
                       line=row_lines[r], column=col)
        ang[(kind, side)] = np.radians(a) if not is_rad else a

    def unit(side):
        t, p = np.clip(ang[("theta", side)], 0.0, np.pi / 2), ang[("phi", side)]
        # theta = 90 deg is the horizon: cos must be exactly 0 (np.cos(pi/2) = 6e-17 > 0 would
        # pass validation as "above the horizon" and blow up the BRDF*cos conversion)
        cos_t = np.where(t >= np.pi / 2, 0.0, np.cos(t))
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), cos_t], -1)

    wi, wo = unit("i"), unit("o")
    value = np.stack([column(*chan_cols[c]) for c in channels], -1)

    def per_channel(aux):
        cols = families[aux]
        return np.stack([column(*cols[c if c in cols else "Y"]) for c in channels], -1)

    sigma = per_channel("sigma") if "sigma" in families else None
    weight = per_channel("weight") if "weight" in families else np.ones_like(value)

    # ---------------------------------------------------------------- validate (file units)
    data = GonioData(wi=wi, wo=wo, value=value, weight=weight, sigma=sigma,
                     channels=channels, metadata=metadata)
    try:
        data.validate(allow_negative_sigmas=allow_negative_sigmas)
    except DataError as e:
        raise _map_validate_error(name, e, data, row_lines, angle_cols, chan_cols, families,
                                  channels, allow_negative_sigmas) from None

    # ---------------------------------------------------------------- convert to BRDF
    cos_o = wo[:, 2]
    value = _to_brdf(qty, value, cos_o)
    if sigma is not None:
        sigma = _to_brdf(qty, sigma, cos_o)
    md = dict(metadata)
    md.pop("quantity", None)
    md.update({"source": name, "format": "csv", "quantity_in_file": qty})
    return GonioData(wi=wi, wo=wo, value=value, weight=weight, sigma=sigma, channels=channels,
                     metadata=md)


def _map_validate_error(name, e, data, row_lines, angle_cols, chan_cols, families, channels,
                        allow_negative_sigmas):
    """Turn ``sample i: ...`` from :meth:`GonioData.validate` into file/line/column."""
    msg = str(e)
    m = re.match(r"sample (\d+): (.*)$", msg, re.S)
    if not m:
        return DataError(f"{name}: {msg}")
    i, rest = int(m.group(1)), m.group(2)
    # the field the message is about: its first word, or "negative weight ..."
    field = "weight" if rest.startswith("negative weight") else rest.split(" ", 1)[0]
    col = None
    if field in ("wi", "wo"):
        side = "i" if field == "wi" else "o"
        col = angle_cols[("theta", side)][1]
    elif field in ("value", "sigma", "weight"):
        cols = chan_cols if field == "value" else families.get(field, {})
        v = getattr(data, field)[i]
        bad = ~np.isfinite(v) | (v < 0)
        if field == "value" and data.sigma is not None and np.isfinite(v).all():
            # the channel that failed: more than allow_negative_sigmas sigma below 0
            bad = v < -allow_negative_sigmas * data.sigma[i]
        k = int(np.flatnonzero(bad)[0]) if bad.any() else int(np.argmin(v))
        key = channels[k] if channels[k] in cols else "Y"
        col = cols[key][1] if key in cols else None
    return _err(name, rest, line=row_lines[i], column=col)


def _fmt(x: float) -> str:
    return repr(float(x))


def write_csv(data: GonioData, path, angles: str = "deg", quantity: str = "brdf") -> None:
    """Write ``data`` in the format read by :func:`read_csv`: ``# key: value`` metadata comments
    (JSON values), angle columns in degrees (``angles="deg"``) or ``*_rad`` columns, value columns
    of the family ``quantity`` (default ``brdf``: BRDF in 1/sr), ``sigma`` columns if present and
    ``weight`` columns if any weight differs from 1. Numbers are written with 17 significant
    digits, so a round trip reproduces the values to float64 round-off."""
    if angles not in ("deg", "rad"):
        raise ValueError(f"angles must be 'deg' or 'rad', got {angles!r}")
    if quantity not in QUANTITIES:
        raise ValueError(f"quantity must be one of {sorted(QUANTITIES)}, got {quantity!r}")
    for c in data.channels:
        if not c or re.search(r"[\s,;#]", c):
            raise DataError(f"write_csv: channel name {c!r} cannot be a CSV column suffix")
    n, nc = data.n, data.n_channels
    wo_z = data.wo[:, 2]
    if quantity == "brdf":
        factor = np.ones(n)
    elif quantity == "brf":
        factor = np.full(n, np.pi)
    else:
        factor = np.clip(wo_z, 0.0, None)
    a = data.angles_deg()
    if angles == "deg":
        names = ["theta_i", "phi_i", "theta_o", "phi_o"]
        cols = [a["theta_i"], a["phi_i"], a["theta_o"], a["phi_o"]]
    else:
        names = ["theta_i_rad", "phi_i_rad", "theta_o_rad", "phi_o_rad"]
        cols = [np.arctan2(np.hypot(w[:, 0], w[:, 1]), w[:, 2]) if k == 0
                else np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * np.pi)
                for w in (data.wi, data.wo) for k in (0, 1)]
    if angles == "deg":
        # arccos loses precision near the pole; atan2 keeps full relative precision
        cols[0] = np.degrees(np.arctan2(np.hypot(data.wi[:, 0], data.wi[:, 1]), data.wi[:, 2]))
        cols[2] = np.degrees(np.arctan2(np.hypot(data.wo[:, 0], data.wo[:, 1]), data.wo[:, 2]))
    sfx = [_suffix_from_channel(c, nc) for c in data.channels]
    for k in range(nc):
        names.append(quantity + sfx[k])
        cols.append(data.value[:, k] * factor)
    if data.sigma is not None:
        for k in range(nc):
            names.append("sigma" + sfx[k])
            cols.append(data.sigma[:, k] * factor)
    if not np.all(data.weight == 1.0):
        if np.all(data.weight == data.weight[:, :1]):
            names.append("weight")
            cols.append(data.weight[:, 0])
        else:
            for k in range(nc):
                names.append("weight" + sfx[k])
                cols.append(data.weight[:, k])
    out = []
    for key, val in data.metadata.items():
        if not re.fullmatch(r"[A-Za-z_][\w.\-]*", str(key)) or key == "quantity":
            continue
        try:
            text = json.dumps(val)
        except TypeError:
            text = json.dumps(str(val))
        out.append(f"# {key}: {text}")
    out.append(f"# quantity: {quantity}")
    out.append(",".join(names))
    table = np.stack(cols, -1)
    out.extend(",".join(_fmt(x) for x in row) for row in table)
    write_text_atomic(path, "\n".join(out) + "\n")
