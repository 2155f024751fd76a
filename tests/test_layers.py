"""The package's layering, enforced (docs/architecture.md, "The layer rule").

Every import in ``brdf_fit`` and ``data_synth`` is read from the source (function-local ones
too), resolved to the module it loads, and checked:

* a module imports only from its own layer or below (:data:`LAYERS`);
* the module graph has no cycle;
* no ``importlib`` / ``__import__`` (modules are imported by name, in plain import statements);
* no module imports a private (``_name``) object from a module of another subpackage.

Each rule has a negative control: the checker is run on the real sources with one deliberately
bad import added, and must report it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("brdf_fit", "data_synth")

#: module prefix -> layer; the longest matching prefix decides. A module may import only from
#: its own layer or a lower one.
LAYERS = {
    "brdf_fit._version": 0,
    "brdf_fit._xla": 0,
    "brdf_fit.core": 0,
    "brdf_fit.data": 0,
    "brdf_fit.models": 1,
    "brdf_fit.registry": 2,
    "brdf_fit.io": 2,
    "brdf_fit.tables": 3,
    "brdf_fit.verify": 3,
    "brdf_fit.fitting": 4,
    "brdf_fit.convert": 5,
    "brdf_fit.selection": 6,
    "brdf_fit.plot": 6,
    "brdf_fit.render": 6,
    "brdf_fit.envmap": 6,  # the environments that light a render
    "brdf_fit.report": 6,
    # the synthetic instrument uses the library; only the application layer above uses it
    "data_synth": 7,
    "brdf_fit.demo": 7,
    "brdf_fit.cli": 8,
    "brdf_fit.__main__": 8,
    "brdf_fit": 9,  # the package's __init__: the public API, re-exporting every layer
}


#: what loads a module from a string (importlib.resources, which reads package data, is fine)
DYNAMIC_IMPORTS = ("import_module", "__import__(", "importlib.util", "importlib.machinery")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def read_sources() -> dict[str, tuple[str, bool]]:
    """module name -> (source, is_package)."""
    out = {}
    for pkg in PACKAGES:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            out[module_name(p)] = (p.read_text(), p.name == "__init__.py")
    return out


def layer(mod: str) -> int:
    best = None
    for prefix, n in LAYERS.items():
        if (mod == prefix or mod.startswith(prefix + ".")) and (
            best is None or len(prefix) > len(best[0])
        ):
            best = (prefix, n)
    if best is None:
        raise KeyError(f"module {mod} has no layer: add it to LAYERS in tests/test_layers.py")
    return best[1]


def subpackage(mod: str, modules) -> str:
    return mod if mod in modules and modules[mod][1] else mod.rpartition(".")[0]


def imports_of(mod: str, source: str, is_pkg: bool, modules) -> list[tuple[str, str, int]]:
    """``(imported module, imported name or '', line)`` for every import statement in
    ``source`` (function-local ones too; ``if TYPE_CHECKING:`` blocks are skipped)."""
    tree = ast.parse(source)
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip.update(id(n) for n in ast.walk(node) if n is not node)
    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
    out = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out += [(a.name, "", node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                target = ".".join(base[: len(base) - node.level + 1] + ([node.module]
                                                                        if node.module else []))
            else:
                target = node.module
            for a in node.names:
                sub = f"{target}.{a.name}"
                if sub in modules:  # "from pkg import submodule" imports the submodule
                    out.append((sub, "", node.lineno))
                else:
                    out.append((target, a.name, node.lineno))
    return out


def violations(modules: dict[str, tuple[str, bool]]) -> list[str]:
    bad = []
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for mod, (src, is_pkg) in modules.items():
        for i, line in enumerate(src.splitlines(), 1):
            if any(s in line for s in DYNAMIC_IMPORTS):
                bad.append(f"{mod}:{i}: imports by name at run time: {line.strip()}")
        for target, name, line in imports_of(mod, src, is_pkg, modules):
            if target.split(".")[0] not in PACKAGES:
                continue
            if target not in modules:
                bad.append(f"{mod}:{line}: imports {target}, which does not exist")
                continue
            if target != mod:
                graph[mod].add(target)
            if layer(target) > layer(mod):
                bad.append(f"{mod}:{line}: layer {layer(mod)} imports {target} "
                           f"(layer {layer(target)})")
            if (name.startswith("_") and not name.startswith("__")
                    and subpackage(target, modules) != subpackage(mod, modules)):
                bad.append(f"{mod}:{line}: imports the private {name} from {target}, "
                           "a module of another subpackage")
    # cycles: depth-first search, report each back edge once
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                cyc = stack[stack.index(t):] + [t]
                bad.append("import cycle: " + " -> ".join(cyc))
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    return bad


@pytest.fixture(scope="module")
def sources():
    return read_sources()


def test_every_module_has_a_layer(sources):
    for mod in sources:
        layer(mod)


def test_the_package_keeps_its_layers(sources):
    assert violations(sources) == []


def _with_line(sources, mod, line):
    out = dict(sources)
    src, is_pkg = out[mod]
    out[mod] = (src + "\n" + line + "\n", is_pkg)
    return out


@pytest.mark.parametrize("mod, line, expect", [
    # a function-local upward import (core -> fitting)
    ("brdf_fit.core.numerics", "def f():\n    from brdf_fit.fitting import single", "layer 0"),
    # a model importing the registry
    ("brdf_fit.models.lambert", "from brdf_fit import registry", "layer 1 imports"),
    # the library importing the synthetic instrument
    ("brdf_fit.fitting.single", "import data_synth.plans", "layer 4 imports"),
    # library code importing through the public __init__ instead of the defining module
    ("brdf_fit.verify.checks", "from brdf_fit import fit", "(layer 9)"),
    # a cycle inside one layer (spectra imports fresnel; now fresnel imports spectra back)
    ("brdf_fit.core.fresnel", "from brdf_fit.core import spectra", "import cycle"),
    # a module list loaded by name
    ("brdf_fit.registry",
     "import importlib\nward = importlib.import_module('brdf_fit.models.ward')",
     "imports by name"),
    # a private helper imported across subpackages
    ("brdf_fit.verify.albedo", "from brdf_fit.core.quadrature import _gl01", "private _gl01"),
])
def test_a_deliberate_violation_is_reported(sources, mod, line, expect):
    bad = violations(_with_line(sources, mod, line))
    assert any(expect in b for b in bad), bad
