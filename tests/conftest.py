"""Test configuration: float64, strict dtype promotion, warnings as errors (pyproject.toml).

Shared jitted helpers live in ``tests/_helpers.py`` so every test module reuses one compilation.
"""

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
