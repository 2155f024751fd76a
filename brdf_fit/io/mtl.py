"""Wavefront material library (``.mtl``) reader.

What a statement *means* as a BRDF is not decided here (see :mod:`brdf_fit.convert.mtl`); this
module only reads the file faithfully, checks every value, and keeps what it does not model.

Format (P. Bourke's transcription of the Alias|Wavefront "MTL material format", Lightwave-era
Object Files appendix; the physically based extension proposed by Exocortex, as documented in
tinyobjloader's ``pbr-mtl.md``; summary in the project's ``formats.md`` 2.1):

* one statement per line, ``keyword value ...``; keywords are matched case-insensitively
  (``Kd`` = ``kd``), values are separated by blanks or tabs; ``#`` starts a comment (also after a
  statement); a line ending in ``\\`` continues on the next (Bourke); CRLF line ends and a UTF-8
  byte-order mark are accepted; a file that is not UTF-8 is read as Latin-1 (every byte is a
  character, so names survive);
* ``newmtl NAME`` starts a material (the name is the rest of the line, blanks included); every
  other statement belongs to the latest ``newmtl``;
* colours ``Ka`` ``Kd`` ``Ks`` ``Ke`` ``Tf``: one value (grey) or three (r g b), each >= 0
  (``Ke`` and the others may exceed 1: no upper bound is imposed here); the ``spectral`` and
  ``xyz`` colour forms are recorded in :attr:`MtlMaterial.ignored`;
* scalars: ``Ns`` >= 0 (Bourke: "normally 0 to 1000"; larger values occur and are kept),
  ``Ni`` > 0, ``d`` in [0, 1], ``Tr`` in [0, 1] (non-standard, common: ``d = 1 - Tr``; when a
  material has both, ``d`` wins and the ``Tr`` statement goes to ``ignored`` with the reason),
  ``illum`` an integer 0-10; PBR extension ``Pr`` ``Pm`` in [0, 1], ``Ps`` ``Pc`` ``Pcr``
  ``aniso`` >= 0, ``anisor`` any finite value;
* texture maps (``map_Kd`` ``map_Ks`` ``map_Ka`` ``map_Ke`` ``map_Ns`` ``map_d`` ``map_Tr``
  ``map_bump`` ``bump`` ``disp`` ``decal`` ``refl`` ``norm`` ``map_Pr`` ``map_Pm`` ``map_Ps``
  ``map_Pc`` ``map_Pcr`` ``map_aat``): options (``-s 1 1 1``, ``-o``, ``-t`` with 1-3 numbers,
  ``-bm``, ``-boost``, ``-mm`` (2), ``-blendu``, ``-blendv``, ``-cc``, ``-clamp``, ``-imfchan``,
  ``-texres``, ``-type``) are parsed off into :attr:`MtlMaterial.map_options`, the rest of the
  line is the file name (blanks allowed).

A statement repeated within a material: the last one wins and the earlier one is recorded in
``ignored`` (with the reason). Anything else that is not modelled (``sharpness``, unknown
keywords, dialect keywords such as ``Pcc``) is recorded in ``ignored`` as ``(line, text)``, never
an error.

Errors are :class:`MtlError`: one line, ``"{path}:{line}: {problem}"``, or
``"{path}: {problem}"`` for the file as a whole (``line`` 0: it cannot be read); an empty file
or one without materials is reported at line 1.
With ``skip_bad=True`` a material holding a bad statement is dropped, its error collected, and
reading goes on at the next ``newmtl``; :func:`read_mtl` and :func:`parse_mtl` then return a
:class:`MtlReadResult`.
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import NamedTuple

from brdf_fit.data import DataError

__all__ = ["MtlError", "MtlMaterial", "MtlReadResult", "read_mtl", "parse_mtl",
           "MTL_COLOURS", "MTL_SCALARS", "MTL_MAPS"]

#: colour statements (canonical spelling); 1 value (grey) or 3
MTL_COLOURS = ("Ka", "Kd", "Ks", "Ke", "Tf")
#: scalar statements -> (lo, hi, lo_open): the accepted interval (None: unbounded)
MTL_SCALARS = {
    "Ns": (0.0, None, False),
    "Ni": (0.0, None, True),
    "d": (0.0, 1.0, False),
    "Tr": (0.0, 1.0, False),
    "Pr": (0.0, 1.0, False),
    "Pm": (0.0, 1.0, False),
    "Ps": (0.0, None, False),
    "Pc": (0.0, None, False),
    "Pcr": (0.0, None, False),
    "aniso": (0.0, None, False),
    "anisor": (None, None, False),
}
#: texture-map statements (canonical spelling)
MTL_MAPS = ("map_Ka", "map_Kd", "map_Ks", "map_Ke", "map_Ns", "map_d", "map_Tr", "map_bump",
            "bump", "disp", "decal", "refl", "norm", "map_Pr", "map_Pm", "map_Ps", "map_Pc",
            "map_Pcr", "map_aat")
#: map options -> (min, max) number of arguments; the numeric ones take up to max numbers
_MAP_OPTIONS = {"-blendu": (1, 1), "-blendv": (1, 1), "-bm": (1, 1), "-boost": (1, 1),
                "-cc": (1, 1), "-clamp": (1, 1), "-imfchan": (1, 1), "-mm": (2, 2),
                "-o": (1, 3), "-s": (1, 3), "-t": (1, 3), "-texres": (1, 1), "-type": (1, 1)}
#: options whose arguments are words, not numbers
_WORD_OPTIONS = ("-blendu", "-blendv", "-cc", "-clamp", "-imfchan", "-type")

_CANON = {k.lower(): k for k in (*MTL_COLOURS, *MTL_SCALARS, *MTL_MAPS, "illum", "newmtl")}
# A decimal number as C's strtod reads it, without inf/nan/hex: what MTL writers produce.
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\Z")


class MtlError(DataError):
    """A bad MTL file: the message is one line, ``"{path}:{line}: {problem}"``. Attributes
    ``path``, ``line`` (0: the file as a whole), ``problem`` and ``material`` (the name of the
    material being read, or None)."""

    def __init__(self, path: str, line: int, problem: str, material: str | None = None):
        self.path, self.line, self.problem, self.material = str(path), int(line), problem, material
        where = self.path if self.line == 0 else f"{self.path}:{self.line}"  # 0: the file
        one_line = " ".join(f"{where}: {problem}".split())
        super().__init__(one_line)


@dataclasses.dataclass(frozen=True)
class MtlMaterial:
    """One ``newmtl`` block, as written (absent statements are None; see the module docstring).

    Colours are 3-tuples of float (a single value in the file gives a grey triple); ``d`` holds
    ``1 - Tr`` when only ``Tr`` was given; ``maps`` maps the canonical statement name (``map_Kd``)
    to its file name and ``map_options`` to its options (option -> tuple of the argument strings);
    ``ignored`` holds ``(line, text)`` of the statements not modelled (``text`` is the statement
    as written, plus ``" -- reason"`` when it was overridden)."""

    name: str
    path: str
    line: int
    Kd: tuple[float, float, float] | None = None
    Ks: tuple[float, float, float] | None = None
    Ka: tuple[float, float, float] | None = None
    Ke: tuple[float, float, float] | None = None
    Tf: tuple[float, float, float] | None = None
    Ns: float | None = None
    Ni: float | None = None
    d: float | None = None
    illum: int | None = None
    Pr: float | None = None
    Pm: float | None = None
    Ps: float | None = None
    Pc: float | None = None
    Pcr: float | None = None
    aniso: float | None = None
    anisor: float | None = None
    maps: dict[str, str] = dataclasses.field(default_factory=dict)
    map_options: dict[str, dict[str, tuple[str, ...]]] = dataclasses.field(default_factory=dict)
    ignored: tuple[tuple[int, str], ...] = ()

    @property
    def where(self) -> str:
        """``"path:line"`` of the ``newmtl`` statement."""
        return f"{self.path}:{self.line}"


class MtlReadResult(NamedTuple):
    """What ``skip_bad=True`` returns: the good materials, in file order, and one
    :class:`MtlError` per dropped material (or stray statement), in file order."""

    materials: list[MtlMaterial]
    errors: list[MtlError]


# ----------------------------------------------------------------------------- parsing


def _logical_lines(text: str):
    """``(line_number, statement)`` with comments stripped, blank lines skipped and ``\\``
    continuations joined (numbered by their first physical line)."""
    if text.startswith("\ufeff"):
        text = text[1:]
    pending, start = "", 0
    for k, raw in enumerate(text.splitlines(), start=1):
        body = raw.split("#", 1)[0]
        if not pending:
            start = k
        stripped = body.rstrip()
        if stripped.endswith("\\") and "#" not in raw:
            pending += stripped[:-1] + " "
            continue
        full = (pending + body).strip()
        pending = ""
        if full:
            yield start, full
    if pending.strip():
        yield start, pending.strip()


def _number(tok: str, key: str, fail) -> float:
    if not _NUMBER.match(tok):
        fail(f"{key}: unknown numeric syntax {tok!r} (expected a decimal number such as 0.5 "
             "or 1e-3)")
    return float(tok)


def _check_range(key: str, v: float, fail) -> None:
    lo, hi, lo_open = MTL_SCALARS[key]
    if not math.isfinite(v):
        fail(f"{key}: value {v!r} is not finite")
    if lo is not None and (v <= lo if lo_open else v < lo):
        fail(f"{key} {v:g} out of range: must be {'>' if lo_open else '>='} {lo:g}"
             + (f" and <= {hi:g}" if hi is not None else ""))
    if hi is not None and v > hi:
        fail(f"{key} {v:g} out of range: must lie in [{lo:g}, {hi:g}]")


def _parse_map(key: str, args: list[str], fail):
    opts: dict[str, tuple[str, ...]] = {}
    k = 0
    while k < len(args) and args[k].lower() in _MAP_OPTIONS and k + 1 < len(args):
        opt = args[k].lower()
        lo, hi = _MAP_OPTIONS[opt]
        vals = []
        k += 1
        while k < len(args) and len(vals) < hi:
            tok = args[k]
            if opt not in _WORD_OPTIONS and not _NUMBER.match(tok):
                break
            if opt in _WORD_OPTIONS and len(vals) >= lo:
                break
            vals.append(tok)
            k += 1
        if len(vals) < lo:
            fail(f"{key}: option {opt} needs {lo} value(s), got {len(vals)}")
        opts[opt] = tuple(vals)
    name = " ".join(args[k:])
    if not name:
        fail(f"{key}: no file name")
    return name, opts


class _Fail(Exception):
    """A problem found in the current statement (its text is ``args[0]``)."""


def _fail(problem: str):
    raise _Fail(problem)


def _accept(cur: dict, key: str, line: int, stmt: str) -> None:
    """Record that ``key`` was set on ``line``; an earlier setting goes to ``ignored``."""
    lines = cur["_lines"]
    if key in lines:
        prev = lines[key]
        cur["_ignored"].append((prev[0], f"{prev[1]} -- overridden by line {line}"))
    lines[key] = (line, stmt)


def parse_mtl(text: str, path: str = "<string>", skip_bad: bool = False):
    """Materials of an MTL text (module docstring). ``path`` names the source in messages.
    Returns ``list[MtlMaterial]``; with ``skip_bad=True`` a :class:`MtlReadResult` (bad
    materials dropped and reported). Raises :class:`MtlError` (without ``skip_bad``: at the first
    problem)."""
    path = str(path)
    materials: list[MtlMaterial] = []
    errors: list[MtlError] = []
    seen: dict[str, int] = {}
    cur: dict | None = None  # the material being read
    bad = False  # the current material had an error (skip_bad): skip to the next newmtl

    def finish():
        if cur is not None and not bad:
            fields = dict(cur)
            set_lines = fields.pop("_lines")
            ignored = fields.pop("_ignored")
            if fields.get("_tr") is not None:
                tr_line, tr_text, tr = fields["_tr"]
                if "d" in set_lines:
                    ignored.append((tr_line, f"{tr_text} -- d on line {set_lines['d'][0]} wins"))
                else:
                    fields["d"] = 1.0 - tr
            fields.pop("_tr")
            ignored.sort(key=lambda e: e[0])
            materials.append(MtlMaterial(**fields, ignored=tuple(ignored)))

    for line, stmt in _logical_lines(text):
        parts = stmt.split()
        word = parts[0]
        key = _CANON.get(word.lower(), word)
        args = parts[1:]

        try:
            if key == "newmtl":
                finish()
                cur, bad = None, False
                name = stmt[len(word):].strip()
                if not name:
                    _fail("newmtl without a material name")
                if name in seen:
                    _fail(f"duplicate material name {name!r} (first defined on line {seen[name]})")
                seen[name] = line
                cur = {"name": name, "path": path, "line": line, "maps": {},
                       "map_options": {}, "_lines": {}, "_ignored": [], "_tr": None}
                continue
            if bad:
                continue
            if cur is None:
                _fail(f"statement {word!r} before any newmtl")
            if key in MTL_COLOURS:
                if args and args[0].lower() in ("spectral", "xyz"):
                    cur["_ignored"].append((line, f"{stmt} -- {args[0].lower()} colours are "
                                                  "not read"))
                    continue
                if len(args) not in (1, 3):
                    _fail(f"{key} takes 1 value (grey) or 3 (r g b), got {len(args)}")
                vals = [_number(t, key, _fail) for t in args]
                for v in vals:
                    if not math.isfinite(v):
                        _fail(f"{key}: value {v!r} is not finite")
                    if v < 0:
                        _fail(f"{key}: negative colour value {v:g}")
                _accept(cur, key, line, stmt)
                cur[key] = tuple(vals * 3 if len(vals) == 1 else vals)
            elif key in MTL_SCALARS:
                if len(args) != 1:
                    _fail(f"{key} takes 1 value, got {len(args)}")
                v = _number(args[0], key, _fail)
                _check_range(key, v, _fail)
                _accept(cur, key, line, stmt)
                if key == "Tr":
                    cur["_tr"] = (line, stmt, v)
                else:
                    cur[key] = v
            elif key == "illum":
                if len(args) != 1:
                    _fail(f"illum takes 1 value, got {len(args)}")
                tok = args[0]
                if not re.fullmatch(r"[+-]?\d+", tok) or not 0 <= int(tok) <= 10:
                    _fail(f"illum must be an integer 0-10, got {tok!r}")
                _accept(cur, key, line, stmt)
                cur["illum"] = int(tok)
            elif key in MTL_MAPS:
                name, opts = _parse_map(key, args, _fail)
                _accept(cur, key, line, stmt)
                cur["maps"][key] = name
                cur["map_options"][key] = opts
            else:
                cur["_ignored"].append((line, stmt))
        except _Fail as f:
            err = MtlError(path, line, f.args[0], cur["name"] if cur is not None else None)
            if not skip_bad:
                raise err from None
            errors.append(err)
            # skip to the next newmtl: the rest of a bad material, of a nameless or duplicate
            # one, or a run of statements before the first newmtl (reported once)
            bad = True
            if key == "newmtl":
                cur = None
    finish()
    if not materials and not errors:
        problem = ("empty file: no materials" if not text.lstrip("\ufeff").strip()
                   else "no materials: no newmtl statement in the file")
        err = MtlError(path, 1, problem)
        if not skip_bad:
            raise err
        errors.append(err)
    return MtlReadResult(materials, errors) if skip_bad else materials


def read_mtl(path, skip_bad: bool = False):
    """Materials of the MTL file at ``path`` (see :func:`parse_mtl`; UTF-8 with or without a
    byte-order mark, else Latin-1). An unreadable file is an :class:`MtlError` at line 0."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except OSError as e:
        raise MtlError(str(path), 0, f"cannot read the file ({e.strerror or e})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return parse_mtl(text, str(path), skip_bad=skip_bad)
