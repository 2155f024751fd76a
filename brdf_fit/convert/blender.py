"""Export to Blender: a Python script that makes one Principled BSDF node material per fitted
material, a ``.blend`` file holding them, and a Cycles gonioreflectometer to check either
(issue 42).

A fit in a ``blender-principled*`` entry (:mod:`brdf_fit.models.blender_principled`) is the
Principled BSDF's own inputs, so the export is lossless: :func:`material_spec` maps the fitted
parameters to the node's sockets (:func:`~brdf_fit.models.blender_principled.to_blender_inputs`)
and :func:`blender_script` writes a script that, run inside Blender (``blender --background
--python FILE.py``, or executed in a ``bpy`` session), creates (or rebuilds) a node material of
that name: a Principled BSDF wired to a Material Output, every fitted input set, the
distribution "Multiscatter GGX", and, for an anisotropic fit, a Tangent node on the UV map
(the data's x axis is the surface's u direction). It changes nothing else in the file.

Blender's Python module (``bpy``, Blender 4.5 LTS) needs NumPy < 2 and so cannot share this
package's environment: the functions that run Blender (:func:`save_blend`,
:func:`measure_in_cycles`) start the Blender Python that :func:`find_blender_python` finds:

1. ``$BRDF_FIT_BLENDER_PYTHON``: a Python interpreter that imports ``bpy``;
2. ``$BRDF_FIT_BLENDER``: a ``blender`` executable (run as ``blender --background
   --factory-startup --python FILE -- ARGS``);
3. ``.venv-blender/bin/python`` in the current directory (``make blender`` makes it:
   ``pip install bpy==4.5.*`` into a Python 3.11 environment of its own);
4. ``blender`` on the ``PATH``.

:func:`measure_in_cycles` renders a material in Cycles at given direction pairs
(:mod:`brdf_fit.convert.cycles_gonio`): the check that an export reflects what the fitted model
reflects, and a way to make gonioreflectometer data from any Blender material.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import pprint
import shutil
import subprocess
import sys
import tempfile

import numpy as np

from brdf_fit import registry
from brdf_fit._version import __version__
from brdf_fit.convert import cycles_gonio
from brdf_fit.core.atomic import write_text_atomic
from brdf_fit.models.blender_principled import to_blender_inputs

__all__ = ["BLENDER_EXTRA", "BlenderExport", "BlenderNotFound", "ExportError",
           "blender_command", "blender_script", "find_blender_python", "material_spec",
           "measure_in_cycles", "pair_frames", "save_blend", "to_blender", "write_blender"]

#: how to get a Blender Python (the message of :class:`BlenderNotFound`)
BLENDER_EXTRA = ("make blender (a Python 3.11 environment .venv-blender with pip install "
                 "'bpy==4.5.*'), or set BRDF_FIT_BLENDER_PYTHON to a Python that imports bpy, "
                 "or BRDF_FIT_BLENDER to a blender 4.5 executable")
#: the distributions of the node (``ShaderNodeBsdfPrincipled.distribution``)
DISTRIBUTIONS = {True: "MULTI_GGX", False: "GGX"}
#: the longest a Blender run may take before it is stopped (seconds)
BLENDER_TIMEOUT = 600


class BlenderNotFound(RuntimeError):
    """No Blender Python was found (:func:`find_blender_python`)."""


class ExportError(ValueError):
    """A model Blender's Principled BSDF does not hold as fitted."""


@dataclasses.dataclass(frozen=True)
class BlenderExport:
    """One material for Blender: ``spec`` (:func:`material_spec`), how it was made
    (``method``: ``"native"``, the node's own inputs), ``error`` (None: not measured here; the
    entry's parity with Cycles is a test, ``tests/convert/test_blender.py``) and a ``note``."""

    name: str
    spec: dict
    method: str
    error: float | None
    note: str


def to_blender(model: str, params: dict, name: str, geometry=None) -> BlenderExport:
    """The Blender material of a fit in registry entry ``model`` (a ``blender-principled*``
    entry; any other is an :class:`ExportError` naming them). ``geometry`` is accepted for the
    exporters' common signature and not used: the export is the model itself."""
    entry = registry.get(model)
    if entry.target != "blender":
        natives = [e.name for e in registry.entries() if e.target == "blender"]
        raise ExportError(f"{entry.name} is not a Blender model; fit one of {', '.join(natives)} "
                          "(or select --target blender)")
    full = {**{k: np.asarray(v) for k, v in entry.defaults().items()}, **params}
    spec = material_spec(name, full, anisotropic="anisotropic" in entry.param_names)
    return BlenderExport(name=name, spec=spec, method="native", error=None,
                         note="lossless: the Principled BSDF's own inputs (Cycles parity tested)")


def write_blender(path, exports: list[BlenderExport], what: str = "fitted materials"
                  ) -> pathlib.Path:
    """Write ``exports`` as a Blender material script (``.py``, :func:`blender_script`) or a
    ``.blend`` file (:func:`save_blend`, needs Blender's Python)."""
    path = pathlib.Path(path)
    text = blender_script([e.spec for e in exports], what)
    if path.suffix == ".blend":
        return save_blend(text, path)
    if path.suffix != ".py":
        raise ValueError(f"{path}: a Blender export ends in .py (a script) or .blend")
    write_text_atomic(path, text)
    return path


def material_spec(name: str, params: dict, *, anisotropic: bool | None = None,
                  multiscatter: bool = True) -> dict:
    """One material of :func:`blender_script`: ``{"name", "inputs", "distribution",
    "tangent"}`` from a ``blender-principled*`` fit's parameters. ``tangent`` (a Tangent node
    on the UV map) defaults to whether the parameters hold ``anisotropic``."""
    if not name or not isinstance(name, str):
        raise ValueError(f"a material needs a non-empty name, got {name!r}")
    inputs = to_blender_inputs(params)
    tangent = ("anisotropic" in params) if anisotropic is None else bool(anisotropic)
    return {"name": name, "inputs": inputs, "distribution": DISTRIBUTIONS[bool(multiscatter)],
            "tangent": tangent}


_SCRIPT = '''\
"""Blender materials written by brdf_fit {version} ({what}).

Run inside Blender 4.5:  blender --background --python THIS_FILE.py   (or exec() it in a bpy
session). It creates one node material per entry of MATERIALS, named as there: a Principled
BSDF wired to a Material Output with the fitted inputs set (a material of that name that exists
already is rebuilt), and changes nothing else.
"""

import bpy

MATERIALS = {materials}


def make_material(spec):
    mat = bpy.data.materials.get(spec["name"]) or bpy.data.materials.new(spec["name"])
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (300, 0)
    bsdf = nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.distribution = spec["distribution"]
    for socket, value in spec["inputs"].items():
        bsdf.inputs[socket].default_value = value
    links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    if spec["tangent"]:
        # the data's x axis is the surface's u direction
        tangent = nodes.new("ShaderNodeTangent")
        tangent.direction_type = "UV_MAP"
        tangent.location = (-300, -200)
        links.new(tangent.outputs["Tangent"], bsdf.inputs["Tangent"])
    return mat


for _spec in MATERIALS:
    make_material(_spec)
'''


def blender_script(specs: list[dict], what: str = "fitted materials") -> str:
    """The text of a Blender Python script making the materials ``specs``
    (:func:`material_spec` each); ``what`` says where they come from (its docstring)."""
    names = [s["name"] for s in specs]
    if len(set(names)) != len(names):
        raise ValueError(f"material names must be unique, got {names}")
    body = pprint.pformat(specs, indent=1, width=96, sort_dicts=False)  # a Python literal
    return _SCRIPT.format(version=__version__, what=what.replace('"', "'"), materials=body)


# ----------------------------------------------------------------------------- running Blender


def find_blender_python() -> list[str]:
    """The command prefix that runs a Python file in Blender (see the module docstring for the
    order searched); raises :class:`BlenderNotFound` naming how to get one."""
    exe = os.environ.get("BRDF_FIT_BLENDER_PYTHON")
    if exe:
        return [exe]
    blender = os.environ.get("BRDF_FIT_BLENDER")
    if blender:
        return [blender, "--background", "--factory-startup", "--python"]
    local = pathlib.Path(".venv-blender") / "bin" / "python"
    if local.exists():
        return [os.path.abspath(local)]  # not resolve(): the venv's python is a symlink
    found = shutil.which("blender")
    if found:
        return [found, "--background", "--factory-startup", "--python"]
    raise BlenderNotFound(f"no Blender Python found: {BLENDER_EXTRA}")


def blender_command(script: str | os.PathLike, *args: str) -> list[str]:
    """The command that runs ``script`` with ``args`` in the Blender Python found."""
    prefix = find_blender_python()
    if prefix[-1] == "--python":
        return [*prefix, str(script), "--", *args]
    return [*prefix, str(script), *args]


def _run_blender(script, *args: str, timeout: float = BLENDER_TIMEOUT) -> None:
    cmd = blender_command(script, *args)
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"Blender did not finish within {timeout:g} s: {' '.join(cmd)}") \
            from None
    if done.returncode != 0:
        tail = "\n".join((done.stderr or done.stdout).strip().splitlines()[-15:])
        raise RuntimeError(f"Blender exited with {done.returncode} running {script}:\n{tail}")


_SAVE = '''\
import sys
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
script, out = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
exec(compile(open(script, encoding="utf-8").read(), script, "exec"), {"__name__": "m"})
for mat in bpy.data.materials:
    mat.use_fake_user = True  # kept in the file though no object uses it
bpy.ops.wm.save_as_mainfile(filepath=out)
'''


def save_blend(script_text: str, path) -> pathlib.Path:
    """Run a material script (:func:`blender_script`) in an empty Blender file and save it as
    ``path`` (``.blend``), the materials kept with a fake user."""
    path = pathlib.Path(path).resolve()
    if path.suffix != ".blend":
        raise ValueError(f"{path}: a Blender file ends in .blend")
    if not path.parent.is_dir():
        raise ValueError(f"{path.parent}: no such directory")
    with tempfile.TemporaryDirectory(prefix="brdf_fit_blend_") as tmp:
        script = pathlib.Path(tmp) / "materials.py"
        script.write_text(script_text, encoding="utf-8")
        saver = pathlib.Path(tmp) / "save.py"
        saver.write_text(_SAVE, encoding="utf-8")
        _run_blender(saver, str(script), str(path))
    if not path.exists():
        raise RuntimeError(f"Blender ran but wrote no {path}")
    return path


def pair_frames(wi, wo):
    """For each pair (local ``wi``, ``wo``, unit, above the horizon): ``(gamma, n, t)``, the
    angle between the two and the world-space normal and tangent of a quad that, seen from
    ``(0, 0, 1)`` under a sun from ``(sin gamma, 0, cos gamma)``, has the pair in its frame
    (``R wo = (0, 0, 1)``, ``R wi = (sin gamma, 0, cos gamma)``, ``n = R z``, ``t = R x``)."""
    wi = np.asarray(wi, np.float64).reshape(-1, 3)
    wo = np.asarray(wo, np.float64).reshape(-1, 3)
    cos_g = np.clip(np.sum(wi * wo, axis=-1), -1.0, 1.0)
    e1 = wo
    perp = wi - cos_g[:, None] * wo
    norm = np.linalg.norm(perp, axis=-1)
    # wi parallel to wo: any direction perpendicular to wo
    fallback = np.cross(wo, np.where(np.abs(wo[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    perp = np.where(norm[:, None] > 1e-12, perp, fallback)
    e2 = perp / np.linalg.norm(perp, axis=-1, keepdims=True)
    e3 = np.cross(e1, e2)
    E = np.stack([e1, e2, e3], axis=-1)  # columns: the pair's frame in local coordinates
    F = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # columns: v, x, y
    R = F[None] @ np.transpose(E, (0, 2, 1))
    gamma = np.arccos(cos_g)
    return gamma, R[:, :, 2], R[:, :, 0]


def measure_in_cycles(script_text: str, material: str, wi, wo, *,
                      timeout: float = BLENDER_TIMEOUT) -> dict:
    """Render ``material`` (made by ``script_text``, :func:`blender_script`) in Cycles at the
    pairs ``(wi[k], wo[k])`` (local frames: z the normal, x the UV map's u): returns
    ``{"f_cos": (N, 3) f(wi, wo) cos(theta_i), "spread": (N,), "blender": version, "renders":
    count, "seconds": Blender's time}`` (:mod:`brdf_fit.convert.cycles_gonio`). Pairs with the
    same angle between ``wi`` and ``wo`` share a render. Both directions must be above the
    horizon (``wo.z >= 1e-3``: the quad's image is stretched by ``1 / wo.z``)."""
    wi = np.asarray(wi, np.float64).reshape(-1, 3)
    wo = np.asarray(wo, np.float64).reshape(-1, 3)
    if wi.shape != wo.shape:
        raise ValueError(f"wi and wo must pair up, got {wi.shape} and {wo.shape}")
    if np.any(wi[:, 2] <= 0) or np.any(wo[:, 2] < 1e-3):
        raise ValueError("every wi must be above the horizon and every wo at cos >= 1e-3")
    gamma, n, t = pair_frames(wi, wo)
    key = np.round(gamma, 12)
    order, renders = [], []
    for g in np.unique(key):
        idx = np.flatnonzero(key == g)
        order.extend(idx.tolist())
        renders.append({"gamma": float(gamma[idx[0]]),
                        "quads": [{"n": n[k].tolist(), "t": t[k].tolist()} for k in idx]})
    with tempfile.TemporaryDirectory(prefix="brdf_fit_cycles_") as tmp:
        script = pathlib.Path(tmp) / "material.py"
        script.write_text(script_text, encoding="utf-8")
        out = pathlib.Path(tmp) / "answer.json"
        job = pathlib.Path(tmp) / "job.json"
        job.write_text(json.dumps({"script": str(script), "material": material,
                                   "renders": renders, "out": str(out)}), encoding="utf-8")
        _run_blender(cycles_gonio.__file__, str(job), timeout=timeout)
        answer = json.loads(out.read_text(encoding="utf-8"))
    values = np.empty((wi.shape[0], 3))
    spread = np.empty(wi.shape[0])
    values[order] = np.asarray(answer["values"], np.float64)
    spread[order] = np.asarray(answer["spread"], np.float64)
    return {"f_cos": values, "spread": spread, "blender": answer["blender"],
            "renders": len(renders), "seconds": answer["seconds"]}


if __name__ == "__main__":  # pragma: no cover
    print(" ".join(find_blender_python()), file=sys.stderr)
