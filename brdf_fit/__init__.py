"""brdf_fit: a differentiable BRDF toolkit in pure JAX.

The public API is what this module re-exports (``__all__``); the subpackages are its layers
(``docs/architecture.md``). Conventions (frame, directions, eval without cosine, pdf, sample with
uniforms, channels, dtype, units) are written in :mod:`brdf_fit.models._base` and in the README.

The names are loaded on first use (PEP 562 ``__getattr__``, with plain import statements), so
``import brdf_fit`` and the command line's ``--help`` do not pay for JAX, colour-science or
optimistix until a name that needs them is touched.
"""

from brdf_fit._version import __version__ as __version__

#: public name -> the subpackage module that defines it (documentation of the API's layout)
_MODELS = ("AbstractBRDF", "BRDFSample", "Lambert", "MicrofacetBRDF", "Mirror", "Mixture",
           "Scaled", "astype")
_FRESNEL = ("ConductorFresnel", "ConstantFresnel", "DielectricFresnel", "SchlickFresnel")
_MICROFACET = ("GGX", "Beckmann", "BlinnPhongNDF", "SmithHeightCorrelated", "SmithSeparable",
               "VCavity")
_PARAMS = ("Entry", "Param")
_DATA = ("DataError", "GonioData")
_IO = ("read", "write", "read_mtl")
_SINGLE = ("fit", "FitResult")
_PROBLEM = ("FitError", "FitProblem", "ParamLayout")
_BATCH = ("fit_batch", "BatchFitResult")
_CHECKS = ("run_checks", "CheckResult")
_ROUGHNESS = ("alpha_to_roughness", "roughness_to_alpha")
_SELECTION = ("select", "Selection")
_SCENE = ("load_scene", "select_scene")
_EXPORT = ("to_gltf", "to_mitsuba", "mtl_to_ggx")
_TABLES = ("dfg_table", "read_table", "write_table", "Table")
_MODULES = ("registry", "fresnel", "microfacet", "spectra")

__all__ = sorted(
    (*_MODELS, *_FRESNEL, *_MICROFACET, *_PARAMS, *_DATA, *_IO, *_SINGLE, *_PROBLEM, *_BATCH,
     *_CHECKS, *_ROUGHNESS, *_SELECTION, *_SCENE, *_EXPORT, *_TABLES, *_MODULES, "ParameterError",
     "conductor_fresnel", "directional_albedo",
     "__version__")
)


def __getattr__(name: str):
    if name in _MODELS:
        import brdf_fit.models as module
    elif name in _FRESNEL or name == "fresnel":
        from brdf_fit.core import fresnel as module
    elif name in _MICROFACET or name == "microfacet":
        from brdf_fit.core import microfacet as module
    elif name in _PARAMS:
        from brdf_fit.core import params as module
    elif name == "ParameterError":
        from brdf_fit.core import validate as module
    elif name in ("conductor_fresnel", "spectra"):
        from brdf_fit.core import spectra as module
    elif name == "registry":
        import brdf_fit.registry as module
    elif name in _DATA:
        import brdf_fit.data as module
    elif name in _IO:
        import brdf_fit.io as module
    elif name in _SINGLE:
        from brdf_fit.fitting import single as module
    elif name in _PROBLEM:
        from brdf_fit.fitting import problem as module
    elif name in _BATCH:
        from brdf_fit.fitting import batch as module
    elif name in _CHECKS:
        from brdf_fit.verify import checks as module
    elif name == "directional_albedo":
        from brdf_fit.verify import albedo as module
    elif name in _ROUGHNESS:
        from brdf_fit.convert import roughness as module
    elif name in _SELECTION:
        from brdf_fit.selection import selector as module
    elif name in _SCENE:
        from brdf_fit.selection import scene as module
    elif name == "to_gltf":
        from brdf_fit.convert import gltf as module
    elif name == "to_mitsuba":
        from brdf_fit.convert import mitsuba as module
    elif name == "mtl_to_ggx":
        from brdf_fit.convert import mtl as module
    elif name in _TABLES:
        import brdf_fit.tables as module
    else:
        raise AttributeError(f"module 'brdf_fit' has no attribute {name!r}")
    value = module if name in _MODULES else getattr(module, name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return list(__all__)
