"""Synthetic image stacks: a spatially varying material photographed by the virtual
gonioreflectometer, one image per (light, view) pair of a measurement plan, written as the
stack description and images :mod:`brdf_fit.io.stack` reads.

    stack = synth_stack("capture/", "ggx", {"alpha": alpha_map, "f0": f0_map},
                        make_plan("random_sparse", {"n": 40, "seed": 3}), seed=7)

``maps`` gives each spatially varying parameter as an image (H, W) (scalar parameters) or
(H, W, C) (channel parameters); every other parameter takes the model's default. Each texel's
values are its model's BRDF at the plan's directions times lognormal noise of ``noise_sigma``
(relative, drawn from ``seed``), in the stack's ``quantity`` (``brdf`` by default). Texels are
evaluated ``chunk`` at a time (one compiled evaluation of that many texels).
"""

from __future__ import annotations

import pathlib

import numpy as np

__all__ = ["synth_stack", "CHUNK"]

#: texels evaluated per call of the compiled evaluation (its memory: CHUNK x M x C values)
CHUNK = 4096


def synth_stack(folder, model: str, maps: dict, plan, *, seed: int = 0,
                noise_sigma: float = 0.01, fmt: str = "exr", quantity: str = "brdf",
                chunk: int = CHUNK) -> pathlib.Path:
    """Render the stack (module docstring) into ``folder``: ``img_000.exr`` ... and
    ``stack.json``, whose path is returned. ``plan``: a :class:`data_synth.plans.Plan` (its
    ``wi``, ``wo``: one image each) or a pair ``(wi, wo)`` of (M, 3) arrays. ``quantity``:
    ``brdf``, ``brf`` (pi x BRDF) or ``brdfcos`` (BRDF x cos(theta_o)) in the pixels."""
    import jax
    import jax.numpy as jnp

    from brdf_fit import registry
    from brdf_fit.io.stack import write_stack

    wi, wo = (plan.wi, plan.wo) if hasattr(plan, "wi") else plan
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    if not maps:
        raise ValueError("synth_stack: give at least one parameter map")
    shapes = {np.shape(v)[:2] for v in maps.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"synth_stack: maps must share one (H, W), got {sorted(shapes)}")
    H, W = next(iter(shapes))
    N = H * W
    entry = registry.get(model)
    flat = {k: np.asarray(v, float).reshape(N, *np.shape(v)[2:]) for k, v in maps.items()}
    names = list(flat)
    jwi, jwo = jnp.asarray(wi), jnp.asarray(wo)

    def one(*p):
        return entry.build(**dict(zip(names, p, strict=True))).eval(jwi, jwo)

    ev = jax.jit(jax.vmap(one))
    chunk = max(1, min(int(chunk), N))
    parts = []
    for s in range(0, N, chunk):
        e = min(N, s + chunk)
        args = [np.concatenate([a[s:e], np.repeat(a[e - 1:e], chunk - (e - s), 0)])
                for a in flat.values()]  # every call the same shape: one compilation
        parts.append(np.asarray(ev(*args))[:e - s])
    f = np.concatenate(parts)  # (N, M[, C])
    f = f[..., None] if f.ndim == 2 else f
    rng = np.random.default_rng(seed)
    f = f * np.exp(noise_sigma * rng.standard_normal(f.shape))
    factor = {"brdf": np.ones(len(wi)), "brf": np.full(len(wi), np.pi),
              "brdfcos": wo[:, 2]}[quantity]
    images = np.moveaxis(f * factor[None, :, None], 1, 0).reshape(len(wi), H, W, -1)
    if images.shape[-1] == 1:
        images = images[..., 0]
    return write_stack(folder, images, wi, wo, fmt=fmt, quantity=quantity,
                       description=f"synthetic {entry.name} stack, {H}x{W} texels, "
                                   f"{len(wi)} images, noise {noise_sigma:g}, seed {seed}")
