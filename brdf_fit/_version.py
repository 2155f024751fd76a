"""The package version (one place; ``brdf_fit.__version__`` and file provenance read it)."""

__version__ = "0.1.0"
