"""Export to MaterialX: a ``.mtlx`` document of ``open_pbr_surface`` materials (issue 42).

A fit in an ``openpbr-surface*`` entry (:mod:`brdf_fit.models.openpbr`) is the OpenPBR Surface
node's own inputs, so the export is lossless: :func:`to_materialx` maps the fitted parameters to
the node's inputs (:func:`~brdf_fit.models.openpbr.to_openpbr_inputs`) and
:func:`mtlx_document` writes, per material, an ``open_pbr_surface`` shader node with every
fitted input set and a ``surfacematerial`` of the material's name bound to it (MaterialX 1.39
document format: ``<materialx version="1.39">``; names made valid MaterialX identifiers, which
allow letters, digits and ``_``).

:func:`validate_mtlx` loads a document with the MaterialX Python package (``pip install
materialx``, an optional extra) against its standard libraries and returns what
``Document.validate`` says; the tests render an export with MaterialX's own GLSL generator
(``tests/convert/test_materialx.py``).
"""

from __future__ import annotations

import dataclasses
import functools
import re
from xml.sax.saxutils import quoteattr

import numpy as np

from brdf_fit import registry
from brdf_fit._version import __version__
from brdf_fit.core.atomic import write_text_atomic
from brdf_fit.models.openpbr import INPUT_TYPES, to_openpbr_inputs

__all__ = ["MATERIALX_EXTRA", "ExportError", "MaterialXExport", "MaterialXNotFound",
           "mtlx_document", "standard_libraries", "to_materialx", "valid_name", "validate_mtlx",
           "write_mtlx"]

#: how to get the MaterialX Python package (the message of :class:`MaterialXNotFound`)
MATERIALX_EXTRA = "pip install 'brdf_fit[materialx]' (the materialx package, 1.39)"
#: the document version written (the ``open_pbr_surface`` node is in MaterialX 1.39's libraries)
MTLX_VERSION = "1.39"


class ExportError(ValueError):
    """A model OpenPBR Surface does not hold as fitted."""


class MaterialXNotFound(RuntimeError):
    """The MaterialX Python package is not installed."""


@dataclasses.dataclass(frozen=True)
class MaterialXExport:
    """One material for MaterialX: its ``name`` (a valid MaterialX name), the node's
    ``inputs`` (:func:`~brdf_fit.models.openpbr.to_openpbr_inputs`), how it was made
    (``method``: ``"native"``), ``error`` (None: not measured here; parity with MaterialX's
    shader is a test) and a ``note``."""

    name: str
    inputs: dict
    method: str
    error: float | None
    note: str


def valid_name(name: str) -> str:
    """``name`` as a MaterialX element name: every character other than a letter, a digit or
    ``_`` becomes ``_``, and a leading digit gets a ``_`` before it."""
    if not name or not isinstance(name, str):
        raise ValueError(f"a material needs a non-empty name, got {name!r}")
    out = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return "_" + out if out[0].isdigit() else out


def to_materialx(model: str, params: dict, name: str, geometry=None) -> MaterialXExport:
    """The MaterialX material of a fit in registry entry ``model`` (an ``openpbr-surface*``
    entry; any other is an :class:`ExportError` naming them). ``geometry`` is accepted for the
    exporters' common signature and not used: the export is the model itself."""
    entry = registry.get(model)
    if entry.target != "openpbr":
        natives = [e.name for e in registry.entries() if e.target == "openpbr"]
        raise ExportError(f"{entry.name} is not an OpenPBR model; fit one of "
                          f"{', '.join(natives)} (or select --target openpbr)")
    full = {**{k: np.asarray(v) for k, v in entry.defaults().items()}, **params}
    return MaterialXExport(name=valid_name(name), inputs=to_openpbr_inputs(full),
                           method="native", error=None,
                           note="lossless: the open_pbr_surface node's own inputs (MaterialX "
                                "GLSL parity tested)")


def _value(name: str, value) -> str:
    if INPUT_TYPES[name] == "color3":
        return ", ".join(repr(float(x)) for x in value)
    return repr(float(value))


def mtlx_document(exports: list[MaterialXExport], what: str = "fitted materials") -> str:
    """A MaterialX 1.39 document: per export an ``open_pbr_surface`` node ``SR_<name>`` and a
    ``surfacematerial`` ``<name>`` bound to it. Names must be distinct."""
    names = [e.name for e in exports]
    if len(set(names)) != len(names):
        raise ValueError(f"material names must be distinct, got {names}")
    comment = f"brdf_fit {__version__}: {what}".replace("--", "- -")
    lines = ['<?xml version="1.0"?>', f'<materialx version="{MTLX_VERSION}">',
             f"  <!-- {comment} -->"]
    for e in exports:
        shader = f"SR_{e.name}"
        lines.append(f'  <open_pbr_surface name={quoteattr(shader)} type="surfaceshader">')
        for name, value in e.inputs.items():
            lines.append(f"    <input name={quoteattr(name)} type=\"{INPUT_TYPES[name]}\" "
                         f"value={quoteattr(_value(name, value))} />")
        lines.append("  </open_pbr_surface>")
        lines.append(f'  <surfacematerial name={quoteattr(e.name)} type="material">')
        lines.append(f'    <input name="surfaceshader" type="surfaceshader" '
                     f'nodename={quoteattr(shader)} />')
        lines.append("  </surfacematerial>")
    lines.append("</materialx>")
    return "\n".join(lines) + "\n"


def write_mtlx(path, exports: list[MaterialXExport], what: str = "fitted materials"):
    """Write ``exports`` as a ``.mtlx`` document (:func:`mtlx_document`)."""
    if not str(path).endswith(".mtlx"):
        raise ValueError(f"{path}: a MaterialX export ends in .mtlx")
    write_text_atomic(path, mtlx_document(exports, what))
    return path


@functools.cache
def standard_libraries():
    """MaterialX's standard libraries (node definitions and graphs, ``open_pbr_surface``'s
    among them) as one document, loaded once per process (:class:`MaterialXNotFound` without
    the ``materialx`` package)."""
    try:
        import MaterialX as mx
    except ImportError:
        raise MaterialXNotFound(f"reading a .mtlx document needs MaterialX: "
                                f"{MATERIALX_EXTRA}") from None
    libraries = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), libraries)
    return libraries


def validate_mtlx(text: str) -> tuple[bool, str]:
    """``(valid, message)`` of MaterialX's ``Document.validate`` for the document ``text``,
    read with the standard libraries (:func:`standard_libraries`; :class:`MaterialXNotFound`
    without the ``materialx`` package)."""
    libraries = standard_libraries()
    import MaterialX as mx

    doc = mx.createDocument()
    mx.readFromXmlString(doc, text)
    doc.setDataLibrary(libraries)
    valid, message = doc.validate()
    return bool(valid), message
