"""Write and read lookup tables (:class:`~brdf_fit.core.table.Table`) as ``.npz``, OpenEXR, 16-bit
PNG or C/GLSL header files.

``write_table(table, "dfg.png")`` picks the format from the extension (or ``fmt=``), checks the
path and that the format can hold the table *before* doing any work or creating any file (a
:class:`ValueError` with a one-line message otherwise), writes through a temporary file in the same
directory that is renamed into place, and returns the list of paths written.
:func:`read_table` reads any of the four back into a :class:`Table` with its axes, channels and
metadata (recognising the format by its magic bytes, so a renamed file still reads).

Every file embeds the same *descriptor*, a JSON object::

    {"format": "brdf_fit.table", "format_version": 1, "writer": "brdf_fit <version>",
     "meta": {...}, "axes": [Axis.to_dict(), ...], "channels": [...], "shape": [...],
     "dtype": "float64", "sha256": "<hex>", ...format-specific keys}

``sha256`` is the SHA-256 of the table's values as float64, little-endian, C order (before any
quantisation to the file's precision), so it identifies the table, not the file. The metadata is
opaque JSON except for two keys:

* ``meta["layout"]["image_origin"]`` (``"top"``, the default, or ``"bottom"``), used by the image
  formats: with ``"top"`` image row 0 (the first scan line, drawn at the top) holds axis-0
  index 0; with ``"bottom"`` it holds index ``n - 1``, i.e. axis 0 grows upwards as in OpenGL
  texture coordinates. Image columns always follow axis 1 from left to right, so a DFG table with
  axes ``(roughness, mu)`` is the usual "x = mu (N.V), y = roughness" LUT.
* ``meta["roughness_axis"]`` (else ``meta["layout"]["roughness_axis"]``; ``"r"``: the axis named
  ``roughness`` holds ``r`` with ``alpha = r**2``; ``"alpha"``: it holds ``alpha`` itself), used
  by ``.npz`` to add an ``alpha`` node vector (none when neither key is present).

Formats
-------
``.npz``  (any number of axes; values exact, in the table's floating dtype): one array per channel
          (named after it, shape ``(axes[0].n, ...)``), one node vector per axis (named after it),
          ``alpha`` when there is a ``roughness`` axis and ``meta["roughness_axis"]`` is given,
          ``E_avg`` when ``meta["E_avg"]`` is a list (a channel named ``E_avg`` is stored as a
          channel anyway) and ``meta_json``, the descriptor as a 0-d unicode array, so the
          ``.npz`` alone round-trips (``numpy.load`` without pickles). A JSON sidecar with the same
          stem (``dfg.npz`` -> ``dfg.json``) holds the same descriptor.
``.exr``  (2-D tables) OpenEXR 2.0 single-part scan-line image, ``ZIP_COMPRESSION`` (lossless),
          ``FLOAT`` (32-bit) pixels or ``HALF`` with ``half=True``; channel names follow the
          OpenEXR "Interpreting OpenEXR Images" conventions: 1 channel -> ``Y`` (luminance),
          2 -> ``R``, ``G``, 3 -> ``R``, ``G``, ``B``, 4 -> ``R``, ``G``, ``B``, ``A``; more keep
          the table's names. The descriptor (with the name map, ``exr_channels``) is the string
          attribute ``brdf_fit`` of the header. Read back as float32 (half values exactly).
``.png``  (2-D tables, 1-3 channels, values in ``[0, 1]``) 16-bit PNG (ISO/IEC 15948, via
          ``pypng``): ``q = round(65535 v)`` (ties to even), 1 channel -> greyscale (colour
          type 0), 2 -> RGB (colour type 2) with ``B = 0`` as engines load a two-channel LUT,
          3 -> RGB. Read back as ``q / 65535`` (error <= 1/131070). The descriptor is a ``tEXt``
          chunk with keyword ``brdf_fit`` placed before ``IDAT``. No ``gAMA``/``sRGB`` chunk is
          written: the samples are linear data; load the image as UNORM, not sRGB.
``.h``    (any number of axes; finite float32 values) a header valid as C/C++ and as GLSL
          (1.20+, ES 3.00): a ``//`` comment block describing the table (one line,
          ``// brdf_fit: {...}``, is the descriptor), ``#define``s ``NAME_N_<AXIS>``,
          ``NAME_CHANNELS``, ``NAME_SIZE`` and one array ``NAME`` in C order
          (``NAME[((i0 * n1 + i1) * ...) * C + c]``, axis order; ``image_origin`` does not apply),
          ``static const float NAME[NAME_SIZE] = {...};`` under C/C++ (``__STDC__`` or
          ``__cplusplus`` defined) and ``const float NAME[NAME_SIZE] = float[NAME_SIZE](...);``
          otherwise. Values are printed with ``%.9g`` (always with a ``.`` or exponent, so they
          are floating literals in GLSL), which round-trips float32 exactly. ``NAME`` is the file
          stem made a C identifier.

OpenEXR (``pip install OpenEXR``, the 3.x ``OpenEXR.File`` API) and pypng (``pip install pypng``)
are optional: ``pip install 'brdf_fit[tables]'``; they are imported only when needed.
"""

from __future__ import annotations

import io
import json
import math
import os
import pathlib
import re

import numpy as np

from brdf_fit._version import __version__
from brdf_fit.core.atomic import atomic_path
from brdf_fit.core.table import (
    TABLE_FORMAT,
    TABLE_FORMAT_VERSION,
    Axis,
    Table,
    load_table,
    parse_descriptor,
    values_sha256,
)
from brdf_fit.io.exr import read_exr, write_exr

__all__ = ["FORMAT", "FORMAT_VERSION", "FORMATS", "check_output", "write_table", "read_table",
           "values_sha256", "sidecar_path"]

FORMAT = TABLE_FORMAT
#: Bump when the layout changes; readers refuse newer versions than they know.
FORMAT_VERSION = TABLE_FORMAT_VERSION
#: Known formats, by extension (without the dot).
FORMATS = ("npz", "exr", "png", "h")
_EXTRA = "pip install 'brdf_fit[tables]'"
_PNG_KEYWORD = b"brdf_fit"
_EXR_ATTRIBUTE = "brdf_fit"
_EXR_NAMES = {1: ("Y",), 2: ("R", "G"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}
_HALF_MAX = 65504.0
_NPZ_RESERVED = ("meta_json", "alpha", "E_avg")
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto if "
    "inline int long register restrict return short signed sizeof static struct switch typedef "
    "union unsigned void volatile while bool true false in out inout uniform varying attribute "
    "vec2 vec3 vec4 mat2 mat3 mat4 sampler2D precision highp mediump lowp discard".split()
)


# --------------------------------------------------------------------------------------------
# shared helpers


def sidecar_path(path) -> pathlib.Path:
    """The JSON sidecar of an ``.npz`` table: same directory and stem, suffix ``.json``."""
    return pathlib.Path(path).with_suffix(".json")


def _np_values(table: Table) -> np.ndarray:
    v = np.asarray(table.values)
    if not np.issubdtype(v.dtype, np.floating):
        v = v.astype(np.float64)
    return v


def _descriptor(table: Table, values: np.ndarray, **extra) -> dict:
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION, "writer": f"brdf_fit {__version__}",
        "meta": table.meta, "axes": [a.to_dict() for a in table.axes],
        "channels": list(table.channels), "shape": list(values.shape),
        "dtype": str(values.dtype), "sha256": values_sha256(values), **extra,
    }


def _dumps(d: dict) -> str:
    """One-line, ASCII-only JSON (safe in a PNG ``tEXt`` chunk and in a ``//`` comment)."""
    return json.dumps(d, sort_keys=True, ensure_ascii=True, allow_nan=False)


def _parse_descriptor(text: str, where: str) -> dict:
    return parse_descriptor(text, where)


def _table_from(d: dict, values: np.ndarray, where: str) -> Table:
    axes = [Axis.from_dict(a) for a in d["axes"]]
    shape = tuple(a.n for a in axes) + (len(d["channels"]),)
    if values.shape != shape:
        raise ValueError(f"{where}: the data have shape {values.shape}, the metadata says {shape}")
    return Table(values, axes, d["channels"], d.get("meta") or {})


def _image_origin(meta: dict) -> str:
    layout = meta.get("layout") or {}
    if not isinstance(layout, dict):
        raise ValueError(f"meta['layout'] must be a dict, got {type(layout).__name__}")
    origin = layout.get("image_origin", "top")
    if origin not in ("top", "bottom"):
        raise ValueError(f"meta['layout']['image_origin'] must be 'top' or 'bottom', "
                         f"got {origin!r}")
    return origin


def _to_image(values: np.ndarray, origin: str) -> np.ndarray:
    """Table values ``(n0, n1, C)`` -> image ``(rows, cols, C)``, row 0 the top scan line."""
    return values[::-1] if origin == "bottom" else values


def _from_image(image: np.ndarray, origin: str) -> np.ndarray:
    return np.ascontiguousarray(image[::-1] if origin == "bottom" else image)


def _need(module: str, package: str, action: str):
    """The optional module (``OpenEXR`` or ``png``), or an ImportError naming the extra."""
    try:
        if module == "OpenEXR":
            import OpenEXR

            return OpenEXR
        import png

        return png
    except ImportError:
        raise ImportError(f"{action} needs the {package} package: {_EXTRA}") from None


def _format_of(path: pathlib.Path, fmt: str | None) -> str:
    if fmt is not None:
        f = str(fmt).lower().lstrip(".")
        if f not in FORMATS:
            raise ValueError(f"unknown table format {fmt!r}; known: {', '.join(FORMATS)}")
        return f
    f = path.suffix.lower().lstrip(".")
    if f not in FORMATS:
        raise ValueError(f"{path}: unknown extension {path.suffix!r}; use one of "
                         f"{', '.join('.' + f for f in FORMATS)} (or pass fmt=)")
    return f


# --------------------------------------------------------------------------------------------
# checks (all before any work)


def _check_path(path: pathlib.Path, fmt: str) -> None:
    parent = path.parent
    if not parent.is_dir():
        raise ValueError(f"{path}: directory {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{path}: directory {str(parent)!r} is not writable")
    if path.is_dir():
        raise ValueError(f"{path}: is a directory")
    if fmt == "npz" and sidecar_path(path) == path:
        raise ValueError(f"{path}: an .npz table's sidecar would overwrite the table itself")


def _check_range(v: np.ndarray, lo: float, hi: float, what: str) -> None:
    if v.size and not (np.all(np.isfinite(v)) and v.min() >= lo and v.max() <= hi):
        vmin, vmax = np.nanmin(v), np.nanmax(v)
        bad = "" if np.all(np.isfinite(v)) else " and non-finite values"
        raise ValueError(f"{what} need values in [{lo:g}, {hi:g}]; the table has min {vmin:.9g}, "
                         f"max {vmax:.9g}{bad}")


def _check_table(table: Table, values: np.ndarray, fmt: str, half: bool) -> None:
    meta = table.meta
    d = len(table.axes)
    C = len(table.channels)
    try:
        _dumps(meta)
    except ValueError as e:
        raise ValueError(f"table meta must be strict JSON (no NaN/inf): {e}") from None
    if half and fmt != "exr":
        raise ValueError(f"half=True applies only to .exr, not .{fmt}")
    if len(set(table.channels)) != C:
        raise ValueError(f"channel names must be unique, got {list(table.channels)}")
    if fmt in ("exr", "png"):
        _image_origin(meta)
        if d != 2:
            raise ValueError(f".{fmt} holds 2-D tables only; this one has {d} axes "
                             f"{[a.name for a in table.axes]} (use .npz or .h)")
    if fmt == "png":
        if not 1 <= C <= 3:
            raise ValueError(f".png holds 1 to 3 channels; this table has {C} "
                             f"{list(table.channels)}")
        _check_range(values, 0.0, 1.0, ".png tables")
    elif fmt == "exr":
        if half:
            _check_range(values, -_HALF_MAX, _HALF_MAX, ".exr with half=True (float16)")
        if C > 4 and any(not c or len(c) > 255 for c in table.channels):
            raise ValueError("OpenEXR channel names must have 1 to 255 characters")
    elif fmt == "h":
        f32 = float(np.finfo(np.float32).max)
        _check_range(values, -f32, f32, ".h headers (finite float32)")
    elif fmt == "npz":
        names = list(table.channels) + [a.name for a in table.axes]
        for n in names:
            if not _IDENT.match(n):
                raise ValueError(f".npz array names must be identifiers; {n!r} is not")
        if len(set(names)) != len(names):
            raise ValueError(f".npz needs distinct channel and axis names, got channels "
                             f"{list(table.channels)} and axes {[a.name for a in table.axes]}")
        clash = sorted(set(names) & {"meta_json"})
        if clash:
            raise ValueError(f".npz reserves the array name 'meta_json'; rename {clash}")
        rough = _roughness_axis(meta)
        if _has_roughness(table) and rough not in (None, "r", "alpha"):
            raise ValueError(f"meta['roughness_axis'] must be 'r' or 'alpha', got {rough!r}")
        e_avg = meta.get("E_avg")
        if isinstance(e_avg, list):
            try:
                np.asarray(e_avg, dtype=np.float64)
            except (TypeError, ValueError):
                raise ValueError("meta['E_avg'] is a list but not a numeric array") from None


def _roughness_axis(meta: dict):
    """``meta["roughness_axis"]``, else ``meta["layout"]["roughness_axis"]``, else ``None``."""
    layout = meta.get("layout")
    inner = layout.get("roughness_axis") if isinstance(layout, dict) else None
    return meta.get("roughness_axis", inner)


def _has_roughness(table: Table) -> bool:
    return any(a.name == "roughness" for a in table.axes)


# --------------------------------------------------------------------------------------------
# public API


def check_output(path, *, fmt: str | None = None, half: bool = False, n_axes: int = 2
                 ) -> str:
    """Everything :func:`write_table` can refuse without the table, checked before a table is
    computed: the format (from the extension or ``fmt``), the directory, the optional package the
    format needs, ``half`` (``.exr`` only) and the number of axes (images hold two). Returns the
    format name; raises :class:`ValueError` / :class:`ImportError` with a one-line message."""
    path = pathlib.Path(path)
    f = _format_of(path, fmt)
    _check_path(path, f)
    if half and f != "exr":
        raise ValueError(f"{path}: half precision is an .exr option, not .{f}")
    if f in ("exr", "png") and n_axes != 2:
        raise ValueError(f"{path}: .{f} holds 2-D tables; this one has {n_axes} axes "
                         "(use .npz or .h)")
    if f == "exr":
        _need("OpenEXR", "OpenEXR", "writing .exr")
    if f == "png":
        _need("png", "pypng", "writing .png")
    return f


def write_table(table: Table, path, *, fmt: str | None = None, half: bool = False
                ) -> list[pathlib.Path]:
    """Write ``table`` to ``path`` as ``.npz`` (+ ``.json`` sidecar), ``.exr``, ``.png`` or
    ``.h`` (see the module docstring for each layout); return the paths written.

    The format comes from the extension unless ``fmt`` (``"npz"``, ``"exr"``, ``"png"``, ``"h"``)
    is given. ``half=True`` (``.exr`` only) stores OpenEXR ``HALF`` pixels instead of ``FLOAT``.
    Raises :class:`ValueError` before writing anything if the directory is missing or not
    writable, the extension is unknown or the format cannot hold the table (axes, channels,
    value range), and :class:`ImportError` if the format's optional package is missing.
    """
    path = pathlib.Path(path)
    f = _format_of(path, fmt)
    _check_path(path, f)
    values = _np_values(table)
    _check_table(table, values, f, half)
    if f == "npz":
        return _write_npz(table, values, path)
    if f == "exr":
        return _write_exr(table, values, path, half)
    if f == "png":
        return _write_png(table, values, path)
    return _write_h(table, values, path)


def read_table(path) -> Table:
    """Read a table written by :func:`write_table` (any of the four formats, recognised by the
    file's magic bytes, else by its extension)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    with open(path, "rb") as fh:
        magic = fh.read(8)
    if magic.startswith(b"PK"):
        return _read_npz(path)
    if magic.startswith(b"\x76\x2f\x31\x01"):
        return _read_exr(path)
    if magic.startswith(b"\x89PNG\r\n\x1a\n"):
        return _read_png(path)
    f = path.suffix.lower().lstrip(".")
    if f == "h" or magic.startswith(b"//") or magic.startswith(b"#"):
        return _read_h(path)
    raise ValueError(f"{path}: not a table file brdf_fit can read (.npz, .exr, .png or .h)")


# --------------------------------------------------------------------------------------------
# .npz


def _write_npz(table: Table, values: np.ndarray, path: pathlib.Path) -> list[pathlib.Path]:
    meta = table.meta
    arrays = {c: np.ascontiguousarray(values[..., k]) for k, c in enumerate(table.channels)}
    derived = []
    for a in table.axes:
        arrays[a.name] = a.nodes()
    rough = _roughness_axis(meta)
    if _has_roughness(table) and rough in ("r", "alpha") and "alpha" not in arrays:
        r = table.axis("roughness").nodes()
        arrays["alpha"] = r**2 if rough == "r" else r.copy()
        derived.append("alpha")
    if isinstance(meta.get("E_avg"), list) and "E_avg" not in arrays:
        arrays["E_avg"] = np.asarray(meta["E_avg"], dtype=np.float64)
        derived.append("E_avg")
    desc = _descriptor(table, values, derived_arrays=derived)
    text = _dumps(desc)
    arrays["meta_json"] = np.array(text)
    side = sidecar_path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        with atomic_path(side) as tmp_side:
            with open(tmp_side, "w", encoding="utf-8") as fh:
                fh.write(json.dumps(desc, sort_keys=True, indent=2, allow_nan=False) + "\n")
    return [path, side]


def _read_npz(path: pathlib.Path) -> Table:
    side = sidecar_path(path)
    with np.load(path, allow_pickle=False) as z:
        embedded = "meta_json" in z.files
    if not embedded and not side.is_file():
        raise ValueError(f"{path}: no 'meta_json' array and no sidecar {side.name}")
    return load_table(path, None if embedded else side.read_text(encoding="utf-8"))


# --------------------------------------------------------------------------------------------
# .exr


def _exr_names(channels) -> tuple[str, ...]:
    return _EXR_NAMES.get(len(channels), tuple(channels))


def _write_exr(table: Table, values: np.ndarray, path: pathlib.Path, half: bool
               ) -> list[pathlib.Path]:
    _need("OpenEXR", "OpenEXR", "writing .exr")
    origin = _image_origin(table.meta)
    image = _to_image(values, origin)
    names = _exr_names(table.channels)
    desc = _descriptor(table, values, image_origin=origin, pixel_type="HALF" if half else "FLOAT",
                       exr_channels=dict(zip(table.channels, names, strict=True)))
    with atomic_path(path) as tmp:
        write_exr(tmp, image, names, {_EXR_ATTRIBUTE: _dumps(desc)}, half=half)
    return [path]


def _read_exr(path: pathlib.Path) -> Table:
    _need("OpenEXR", "OpenEXR", "reading .exr")
    where = str(path)
    image, names, header = read_exr(path)
    if _EXR_ATTRIBUTE not in header:
        raise ValueError(f"{where}: no {_EXR_ATTRIBUTE!r} header attribute")
    d = _parse_descriptor(str(header[_EXR_ATTRIBUTE]), where)
    planes = []
    for c in d["channels"]:
        n = d["exr_channels"][c]
        if n not in names:
            raise ValueError(f"{where}: EXR channel {n!r} (table channel {c!r}) is missing")
        planes.append(image[..., names.index(n)])
    image = np.stack(planes, axis=-1)
    return _table_from(d, _from_image(image, d.get("image_origin", "top")), where)


# --------------------------------------------------------------------------------------------
# .png


def _write_png(table: Table, values: np.ndarray, path: pathlib.Path) -> list[pathlib.Path]:
    png = _need("png", "pypng", "writing .png")
    origin = _image_origin(table.meta)
    image = _to_image(values, origin)
    rows, cols, C = image.shape
    q = np.rint(np.asarray(image, dtype=np.float64) * 65535.0).astype(np.uint16)
    if C == 2:
        q = np.concatenate([q, np.zeros_like(q[..., :1])], axis=-1)
    planes = q.shape[-1]
    desc = _descriptor(table, values, image_origin=origin, png_quantisation="round(v*65535)",
                       png_planes="RGB" if planes == 3 else "L")
    buf = io.BytesIO()
    writer = png.Writer(width=cols, height=rows, greyscale=planes == 1, bitdepth=16)
    writer.write(buf, q.reshape(rows, cols * planes).tolist())
    chunks = list(png.Reader(bytes=buf.getvalue()).chunks())
    text = _PNG_KEYWORD + b"\x00" + _dumps(desc).encode("latin-1")  # PNG tEXt: keyword NUL text
    chunks.insert(1, (b"tEXt", text))  # right after IHDR, before IDAT
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            png.write_chunks(fh, chunks)
    return [path]


def _png_text(chunks, where: str) -> str:
    import zlib

    for kind, data in chunks:
        if kind == b"tEXt":
            key, _, text = data.partition(b"\x00")
            if key == _PNG_KEYWORD:
                return text.decode("latin-1")
        elif kind == b"iTXt":  # keyword NUL flag method lang NUL tkey NUL text (UTF-8)
            key, _, rest = data.partition(b"\x00")
            if key == _PNG_KEYWORD:
                flag, rest = rest[0], rest[2:]
                rest = rest.split(b"\x00", 2)[2]
                return (zlib.decompress(rest) if flag else rest).decode("utf-8")
    raise ValueError(f"{where}: no {_PNG_KEYWORD.decode()!r} tEXt/iTXt chunk")


def _read_png(path: pathlib.Path) -> Table:
    png = _need("png", "pypng", "reading .png")
    where = str(path)
    data = path.read_bytes()
    d = _parse_descriptor(_png_text(png.Reader(bytes=data).chunks(), where), where)
    width, height, rows, info = png.Reader(bytes=data).read()
    if info["bitdepth"] != 16:
        raise ValueError(f"{where}: expected a 16-bit PNG, got bit depth {info['bitdepth']}")
    planes = info["planes"]
    q = np.array([np.asarray(r, dtype=np.uint16) for r in rows]).reshape(height, width, planes)
    C = len(d["channels"])
    image = q[..., :C].astype(np.float64) / 65535.0
    return _table_from(d, _from_image(image, d.get("image_origin", "top")), where)


# --------------------------------------------------------------------------------------------
# .h


def _c_name(stem: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_]", "_", stem) or "table"
    if name[0].isdigit():
        name = "t_" + name
    if name.startswith("_"):
        name = "t" + name
    if name in _C_KEYWORDS or name.startswith("gl_"):
        name += "_table"
    return name


def _c_float(x: np.float32) -> str:
    s = f"{float(x):.9g}"
    if not any(ch in s for ch in ".en"):
        s += ".0"
    return s


def _write_h(table: Table, values: np.ndarray, path: pathlib.Path) -> list[pathlib.Path]:
    name = _c_name(path.stem)
    NAME = name.upper()
    v32 = np.asarray(values, dtype=np.float32)
    C = len(table.channels)
    size = int(v32.size)
    desc = _descriptor(table, values, c_name=name, c_order="axes then channel")
    idx = "i0"
    for k in range(1, len(table.axes)):
        idx = f"({idx}) * n{k} + i{k}" if k > 1 else f"{idx} * n{k} + i{k}"
    lines = [
        f"// {name}: lookup table written by brdf_fit {__version__} (valid C/C++ and GLSL).",
        f"// kind: {table.meta.get('kind', 'unknown')}; channels: {', '.join(table.channels)}.",
        "// axes (texel centres: x_i = lo + (i + 0.5) (hi - lo) / n; endpoints: "
        "x_i = lo + i (hi - lo) / (n - 1)):",
    ]
    for k, a in enumerate(table.axes):
        grid = "texel centres" if a.centres else "endpoints"
        lines.append(f"//   i{k}: {a.name} in [{a.lo:.9g}, {a.hi:.9g}], n{k} = {a.n}, {grid}")
    lines += [
        f"// element (i0, ..., channel c) is {name}[({idx}) * {C} + c] (C order).",
        "// values: float32, printed with %.9g (exact round trip).",
        f"// brdf_fit: {_dumps(desc)}",
        f"#ifndef {NAME}_H",
        f"#define {NAME}_H",
    ]
    for a in table.axes:
        lines.append(f"#define {NAME}_N_{_c_name(a.name).upper()} {a.n}")
    lines += [
        f"#define {NAME}_CHANNELS {C}",
        f"#define {NAME}_SIZE {size}",
        "#if defined(__STDC__) || defined(__cplusplus)",
        f"static const float {name}[{NAME}_SIZE] = {{",
        "#else",
        f"const float {name}[{NAME}_SIZE] = float[{NAME}_SIZE](",
        "#endif",
    ]
    flat = [_c_float(x) for x in v32.reshape(-1)]
    per = 8
    for i in range(0, size, per):
        tail = "," if i + per < size else ""
        lines.append("    " + ", ".join(flat[i:i + per]) + tail)
    lines += [
        "#if defined(__STDC__) || defined(__cplusplus)",
        "};",
        "#else",
        ");",
        "#endif",
        f"#endif  // {NAME}_H",
        "",
    ]
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="ascii", newline="\n") as fh:
            fh.write("\n".join(lines))
    return [path]


def _read_h(path: pathlib.Path) -> Table:
    where = str(path)
    text = path.read_text(encoding="utf-8")
    m = re.search(r"^// brdf_fit: (\{.*\})\s*$", text, flags=re.MULTILINE)
    if m is None:
        raise ValueError(f"{where}: no '// brdf_fit: {{...}}' metadata line")
    d = _parse_descriptor(m.group(1), where)
    lines = text.splitlines()
    try:
        start = next(i for i, ln in enumerate(lines) if ln.startswith("static const float "))
        start = next(i for i in range(start, len(lines)) if lines[i].startswith("#endif")) + 1
        stop = next(i for i in range(start, len(lines)) if lines[i].startswith("#if"))
    except StopIteration:
        raise ValueError(f"{where}: cannot find the array initialiser") from None
    body = " ".join(lines[start:stop]).replace(",", " ").split()
    try:
        flat = np.array([np.float32(s) for s in body], dtype=np.float32)
    except ValueError as e:
        raise ValueError(f"{where}: bad number in the array ({e})") from None
    shape = tuple(int(a["n"]) for a in d["axes"]) + (len(d["channels"]),)
    if flat.size != math.prod(shape):
        raise ValueError(f"{where}: {flat.size} values, the metadata needs {math.prod(shape)}")
    return _table_from(d, flat.reshape(shape), where)
