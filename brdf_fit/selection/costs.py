"""What a model costs a renderer (module docstring of :mod:`brdf_fit.selection.selector`:
**Cost** and **The cost that decides**): the live figure, nanoseconds per jitted evaluation on
this machine, and the committed one, each entry's cost relative to Lambert measured by
``benchmarks/bench_catalogue_cost.py`` (``brdf_fit/resources/catalogue_cost.json``)."""

from __future__ import annotations

import functools
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.verify.catalogue import COST_FILE

__all__ = ["COST_PAIRS", "COST_ROUNDS", "committed_costs", "live_cost", "measure_cost"]

#: direction pairs per timed call of :func:`measure_cost` and timed calls per candidate
COST_PAIRS = 16384
COST_ROUNDS = 7


def committed_costs() -> dict[str, float]:
    """Each entry's committed evaluation cost relative to Lambert (the selector's docstring),
    from ``brdf_fit/resources/catalogue_cost.json``."""
    doc = _cost_table()
    return {k: float(v["eval"]) for k, v in doc.get("relative", {}).items()}


@functools.cache
def _cost_table() -> dict:
    try:
        return json.loads(COST_FILE.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def _directions(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)

    def hemi(k):
        u1, u2 = rng.random(k), rng.random(k)
        r = np.sqrt(u1)
        return np.stack([r * np.cos(2 * np.pi * u2), r * np.sin(2 * np.pi * u2),
                         np.sqrt(1.0 - u1)], -1)

    return hemi(n), hemi(n)


def measure_cost(model, n: int = COST_PAIRS, rounds: int = COST_ROUNDS) -> float:
    """Nanoseconds per evaluation of ``model.eval`` under ``jit`` (the selector's docstring), of
    the model as a renderer holds it (:meth:`~brdf_fit.models.AbstractBRDF.prepared`: tables a
    plugin builds once per material are not charged to every pair)."""
    wi, wo = (jnp.asarray(a) for a in _directions(n))
    leaves, treedef = jax.tree_util.tree_flatten(model.prepared())

    @jax.jit
    def run(leaves, wi, wo):
        return jax.tree_util.tree_unflatten(treedef, leaves).eval(wi, wo)

    jax.block_until_ready(run(leaves, wi, wo))  # compile
    best = float("inf")
    for _ in range(rounds):
        t0 = time.perf_counter()
        jax.block_until_ready(run(leaves, wi, wo))
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e9


def live_cost(name, model, costs) -> float:
    """The live cost of ``model`` (ns per evaluation), from ``costs`` when it holds ``name``."""
    if costs is not None and name in costs:
        return costs[name]
    cost = measure_cost(model)
    if costs is not None:
        costs[name] = cost
    return cost
