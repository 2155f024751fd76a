"""Table layouts: where the texels sit, what the roughness axis means, and which way images run.

A :class:`Layout` states the three conventions a consumer of a 2-D table must agree on:

* ``centres``: texel centres (node ``i`` of ``N`` at ``(i + 0.5)/N``, what a GPU samples with
  ``LINEAR`` filtering over ``[0, 1]``) or endpoints (``i/(N - 1)``, both ends of the interval
  are nodes);
* ``roughness_axis``: ``"r"`` (perceptual roughness, ``alpha = r^2``, Burley 2012 and glTF 2.0's
  ``roughnessFactor``) or ``"alpha"`` (the GGX width itself);
* ``image_origin``: ``"top"`` when image row 0 holds the smallest roughness (row order of the
  array), ``"bottom"`` when image row 0 holds the largest (OpenGL's texture origin is the
  bottom-left, so an image written top row first and uploaded as-is puts roughness 0 at v = 0).

* ``channels``: what the table stores: ``("A", "B")`` (scale and bias, ``E = F0 A + B``),
  ``("B", "E")`` (bias and ``E = A + B``, Filament's multiple-scattering packing, from which
  ``E = mix(B, E, F0)``) or ``("E",)`` (the albedo with ``F = 1`` only, as Blender Cycles keeps);
* ``masking``: the preset's masking-shadowing term (``--masking`` overrides it).

Columns always run over ``mu = cos(theta_o)`` from 0 to 1 and rows over roughness. The presets
name the engine whose table they reproduce; each engine's convention was read in its source
(files named in ``note``). Where an engine's own table deviates from its stated convention (a
clamp, a shift, a sampling estimator) the preset reproduces the convention, not the deviation,
and ``note`` says what differs.
"""

from __future__ import annotations

import dataclasses

__all__ = ["LAYOUTS", "Layout", "resolve_layout"]


@dataclasses.dataclass(frozen=True)
class Layout:
    name: str
    centres: bool = True
    roughness_axis: str = "r"
    image_origin: str = "top"
    masking: str = "height-correlated"
    channels: tuple[str, ...] = ("A", "B")
    note: str = ""

    def __post_init__(self):
        if self.roughness_axis not in ("r", "alpha"):
            raise ValueError(f"layout {self.name!r}: roughness_axis must be 'r' or 'alpha'")
        if self.image_origin not in ("top", "bottom"):
            raise ValueError(f"layout {self.name!r}: image_origin must be 'top' or 'bottom'")
        if tuple(self.channels) not in CHANNEL_SETS:
            raise ValueError(f"layout {self.name!r}: channels must be one of {CHANNEL_SETS}")

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["channels"] = list(self.channels)
        return d


#: the channel sets a DFG table can be stored as (see :class:`Layout`)
CHANNEL_SETS = (("A", "B"), ("B", "E"), ("E",))


#: the named presets (the default first)
LAYOUTS: dict[str, Layout] = {
    "default": Layout(
        "default",
        note="texel centres; rows r = (j + 0.5)/N with alpha = r^2; columns mu = (i + 0.5)/N",
    ),
    "khronos": Layout(
        "khronos",
        note="glTF-IBL-Sampler lib/source/shaders/filter.frag (LUT pass) as used for the glTF "
             "Sample Viewer's lut_ggx.png: x = N.V, y = r at texel centres, alpha = r^2, "
             "V_SmithGGXCorrelated, R = A, G = B (B = Charlie sheen in its own LUT); the sampler "
             "estimates with 1024 GGX samples and stores 8 bits per channel",
    ),
    "filament": Layout(
        "filament",
        image_origin="bottom",
        channels=("B", "E"),
        note="Filament libs/ibl/src/CubemapIBL.cpp DFG with cmgen --ibl-dfg-multiscatter "
             "(filament/CMakeLists.txt): texel centres, alpha = r^2, height-correlated Smith, "
             "R = B, G = A + B, rows in OpenGL order (row 0 = smallest r); Filament's own table "
             "(1024 Hammersley samples) holds r = (y + 1.5)/N in GL row y, one texel off the "
             "centre it is sampled at; this preset puts r = (y + 0.5)/N there",
    ),
    "ue4": Layout(
        "ue4",
        masking="karis",
        note="Karis 2013, Real Shading in Unreal Engine 4 (IntegrateBRDF, 1024 Hammersley "
             "samples): alpha = Roughness^2, separable Schlick-Smith with k = alpha/2, R = A, "
             "G = B; the texel mapping of Epic's shipped asset is not published (texel centres "
             "assumed)",
    ),
    "cycles": Layout(
        "cycles",
        centres=False,
        channels=("E",),
        note="Blender intern/cycles/app/cycles_precompute.cpp (table_ggx_E, 32x32): endpoints "
             "mu = i/(N-1), r = j/(N-1), alpha = r^2, height-correlated Smith, E = A + B with "
             "F = 1 (2^23 samples per cell, 6 decimals); Cycles clamps mu and r below at 1e-4 "
             "and indexes table_ggx_E[mu][r] (transposed to this array's [r][mu]); this preset "
             "evaluates the exact limits at mu = 0 and r = 0",
    ),
}


def resolve_layout(layout) -> Layout:
    """A :class:`Layout` from ``None`` (the default), a preset name or a ``Layout``."""
    if layout is None:
        return LAYOUTS["default"]
    if isinstance(layout, Layout):
        return layout
    try:
        return LAYOUTS[layout]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}"
        ) from None
