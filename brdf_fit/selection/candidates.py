"""Which registry entries a selection fits: the default candidates, the named families, each
target's native entries (and the anisotropic ones that join when the data show anisotropy), and
which entries a target holds exactly. Data only, and the lookups that check a name
(:func:`brdf_fit.selection.select` uses them; moved out of selector.py, which passed 600
lines)."""

from __future__ import annotations

from brdf_fit import registry

__all__ = ["ANISOTROPIC_CANDIDATES", "DEFAULT_CANDIDATES", "EXACT_EXPORTS", "FAMILIES",
           "TARGETS", "TARGET_CANDIDATES", "anisotropic_candidates", "exports_exactly",
           "family_candidates", "target_candidates"]

#: the default candidates: one or two of each family, diffuse to specular, cheap to costly
DEFAULT_CANDIDATES = (
    "lambert", "oren-nayar", "modified-phong", "blinn-phong", "ward", "beckmann", "ggx",
    "ggx-plastic", "ggx-conductor", "cook-torrance",
)

#: named candidate families (``select(..., family=NAME)``, ``brdf-fit select --family NAME``):
#: the registry entries that answer one question each. ``"all"`` is every registry entry that
#: can be fitted (not a delta lobe): 40-odd fits, minutes, for when the question is open.
FAMILIES = {
    "default": DEFAULT_CANDIDATES,
    # a matte surface: how much retro-reflection and darkening at grazing does it need?
    "diffuse": ("lambert", "oren-nayar", "oren-nayar-qualitative", "minnaert", "lewis"),
    # the Phong catalogue, as old renderers and MTL files carry it
    "phong": ("modified-phong", "modified-phong-fresnel", "blinn-phong", "blinn-phong-approx",
              "phong-energy-normalized", "blinn-phong-microfacet"),
    # isotropic microfacet specular lobes: which NDF, which masking, single or multiple scattering
    "microfacet": ("beckmann", "beckmann-walter", "ggx", "ggx-separable", "ggx-ms",
                   "ggx-ms-turquin", "cook-torrance", "cook-torrance-1982"),
    # diffuse base plus a specular coat: summed, coupled or layered
    "plastic": ("ggx-plastic", "torrance-sparrow", "ashikhmin-shirley", "kelemen",
                "granier-heidrich", "ward"),
    # metals: exact conductor Fresnel, single and multiple scattering
    "conductor": ("ggx-conductor", "ggx-conductor-ms", "ggx", "cook-torrance"),
    # brushed surfaces: two widths
    "anisotropic": ("ggx-aniso", "beckmann-aniso", "ward", "ashikhmin-shirley", "lafortune",
                    "ggx-conductor-aniso"),
}


#: renderers and formats a selection can target
TARGETS = ("mitsuba", "gltf", "blender", "openpbr")
#: the default candidates of a target: its native entries, cheap to costly (anisotropic ones
#: join when the data show anisotropy: :data:`ANISOTROPIC_CANDIDATES`)
TARGET_CANDIDATES = {
    "mitsuba": ("lambert", "mitsuba-roughconductor", "mitsuba-roughconductor-beckmann",
                "mitsuba-roughplastic", "mitsuba-roughplastic-beckmann",
                "mitsuba-principled", "mitsuba-principled-clearcoat",
                "mitsuba-principled-sheen", "mitsuba-principled-tinted"),
    "gltf": ("lambert", "gltf-pbr", "gltf-pbr-specular", "gltf-pbr-clearcoat",
             "gltf-pbr-sheen"),
    "blender": ("blender-principled", "blender-principled-coat", "blender-principled-sheen"),
    "openpbr": ("openpbr-surface", "openpbr-surface-coat", "openpbr-surface-fuzz"),
}
#: the candidates added when :func:`~brdf_fit.selection.anisotropy.detect_anisotropy` finds
#: anisotropy (key None: no target)
ANISOTROPIC_CANDIDATES = {
    None: ("ggx-aniso", "ggx-conductor-aniso"),
    "mitsuba": ("mitsuba-roughconductor-aniso", "mitsuba-roughconductor-beckmann-aniso",
                "mitsuba-principled-aniso"),
    "gltf": ("gltf-pbr-anisotropy",),
    "blender": ("blender-principled-aniso",),
    "openpbr": ("openpbr-surface-aniso",),
}
#: entries of the literature a target holds exactly (besides the target's native entries):
#: Lambert is Mitsuba's ``diffuse`` and glTF's dielectric with ``specularFactor`` 0; glTF's
#: metal branch is ``ggx``; Mitsuba's ``principled`` with metallic 1 is ``ggx-separable``
EXACT_EXPORTS = {
    "mitsuba": ("lambert", "ggx-separable"),
    "gltf": ("lambert", "ggx"),
    "blender": (),
    "openpbr": (),
}


def exports_exactly(name: str, target: str) -> bool:
    """Whether registry entry ``name`` is written to ``target`` with no loss (a native entry of
    the target, or one of :data:`EXACT_EXPORTS`)."""
    e = registry.get(name)
    return e.target == target or e.name in EXACT_EXPORTS.get(target, ())


def target_candidates(target: str) -> tuple[str, ...]:
    """The default candidates of ``target`` (:data:`TARGET_CANDIDATES`)."""
    if target not in TARGETS:
        raise ValueError(f"unknown target {target!r}; known: {', '.join(TARGETS)}")
    return TARGET_CANDIDATES[target]


def anisotropic_candidates(target: str | None) -> tuple[str, ...]:
    """The candidates added when the data show anisotropy (:data:`ANISOTROPIC_CANDIDATES`)."""
    return ANISOTROPIC_CANDIDATES[target]


def family_candidates(family: str) -> tuple[str, ...]:
    """The registry names of a named family (:data:`FAMILIES`; ``"all"``: every non-delta
    entry). An unknown family is a ``ValueError`` that lists the known ones."""
    if family == "all":
        return tuple(e.name for e in registry.entries() if "delta" not in e.tags)
    if family not in FAMILIES:
        raise ValueError(f"unknown family {family!r}; known: "
                         + ", ".join([*FAMILIES, "all"]))
    return FAMILIES[family]
