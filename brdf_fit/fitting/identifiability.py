"""Which entries of a fit the data determine: the codes of an undefined standard error (at
bound, not identifiable, non-finite normal equations) from the normal equations' scaled
rank (:func:`stderr_codes`), the entries called undetermined (:func:`undetermined`), and
the labels of a parameter's entries (``eta[R]``: :func:`entry_labels`,
:func:`parameter_entries`). :mod:`brdf_fit.fitting.problem` re-exports these names.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "RANK_RCOND", "DEAD_COLUMN_REL", "NULL_SHARE", "STDERR_NOTES", "stderr_codes", "stderr_notes",
    "UNDETERMINED_REL_STDERR", "UNDETERMINED_RULE", "undetermined", "entry_labels",
    "parameter_entries",
]

#: Relative threshold of the numerical rank of the normal equations ``A = J^T J`` in the free
#: physical parameters, taken on the correlation-scaled ``R = D^-1/2 A D^-1/2`` (``D = diag(A)``,
#: so the test does not depend on the parameters' units; R's eigenvalues sum to p): an
#: eigenvalue below ``RANK_RCOND * max`` (a singular value of the column-scaled ``J`` below 1e-5
#: of the largest) is a combination of parameters the data determine 1e5 times less well than
#: the best-determined one, i.e. not at all. The rounding of ``J^T J`` in float64 is ~1e-13
#: relative (m ~ 1e4 samples), far below; two parameters that enter only as a product give
#: ~1e-16 (measured), well-posed fits of the test suite >= 1e-5 (measured). For a lower
#: precision the threshold is raised to 1e3 eps of that dtype (1.2e-4 in float32).
RANK_RCOND = 1e-10
#: A parameter whose Jacobian column has a norm below this fraction of the largest column's is
#: not identifiable outright: ``numpy.linalg.pinv`` (rcond 1e-15 on ``A``, i.e. ~3e-8 on the
#: columns of ``J``) drops such a direction and reports a confidently small, meaningless error
#: (gold's red channel at F ~ 1 in the demo: 1e-10).
DEAD_COLUMN_REL = 3e-8
#: A parameter takes part in a rank-deficient direction ``v`` (unit eigenvector of R) when
#: ``|v_i| > NULL_SHARE``: its variance along ``v``, ``v_i^2 / lambda``, is unbounded as lambda
#: -> 0; 0.01 (1e-4 of the direction's squared length) ignores the rounding-level components
#: an eigenvector carries on the well-determined parameters.
NULL_SHARE = 0.01
#: Why a standard error is undefined (NaN), by code (:func:`stderr_codes`; 0: defined).
STDERR_NOTES = {1: "at bound", 2: "not identifiable", 3: "non-finite normal equations"}


def stderr_codes(A, finite=None, xp=np):
    """Per flat free parameter (``A``: ``J^T J`` (p, p) in the physical parameters): 0 when its
    standard error is defined, 2 when it is not identifiable (its Jacobian column vanishes,
    :data:`DEAD_COLUMN_REL`, or it takes part in a direction of numerical rank deficiency,
    :data:`RANK_RCOND`, :data:`NULL_SHARE`), 3 for every parameter when the normal equations
    are not finite (``finite``: that test, default computed from ``A``). NumPy or JAX (jit,
    vmap: ``xp=jnp``); at-bound flags (code 1) are added by the caller (:func:`at_bound`)."""
    p = A.shape[-1]
    if finite is None:
        finite = xp.all(xp.isfinite(A))
    A = xp.where(finite, A, xp.eye(p, dtype=A.dtype))  # no eigensolver on inf/NaN
    d = xp.sqrt(xp.maximum(xp.diagonal(A), 0.0))
    dead = d <= DEAD_COLUMN_REL * xp.max(d)
    ds = xp.where(dead, 1.0, d)
    live = ~dead
    R = xp.where(live[:, None] & live[None, :], A / (ds[:, None] * ds[None, :]), 0.0)
    w, V = xp.linalg.eigh(R)
    rcond = max(RANK_RCOND, 1e3 * float(np.finfo(np.dtype(A.dtype)).eps))
    small = w <= rcond * xp.max(w)
    implicated = xp.any(small[None, :] & (xp.abs(V) > NULL_SHARE), axis=-1)
    code = xp.where(dead | implicated, 2, 0)
    return xp.where(finite, code, 3)


#: A fitted parameter is flagged *undetermined* by the data when its standard error exceeds
#: this fraction of its magnitude: its ~95% interval (+-1.96 sigma) then spans more than +-49%
#: of the value, so the data do not fix it to within a factor of about two. A statement about
#: the data, not the optimiser: such a value can land far from the truth while the fit is at
#: the noise (the demo's gold: F0 in red is ~0.99 whatever (eta, k) give it, and the fit returns
#: k[R] = 1.17 +- 0.71 and eta[R] = 0.0032 +- 0.0021 against a truth of 7.5 and 0.060,
#: relative errors 0.60 and 0.65, where every other parameter of that fit is below 0.03).
#: A parameter whose standard error is undefined because it is not identifiable (code 2 of
#: :func:`stderr_codes`) is undetermined too; one at an interval end is reported as at bound.
UNDETERMINED_REL_STDERR = 0.25
UNDETERMINED_RULE = (f"relative standard error > {UNDETERMINED_REL_STDERR:g}, or not "
                     "identifiable: the data do not determine the value")


def undetermined(value, stderr, note=None) -> np.ndarray:
    """Boolean mask (the shape of ``value``): the entries the data do not determine
    (:data:`UNDETERMINED_REL_STDERR`): a finite standard error above that fraction of ``|value|``,
    or an undefined one whose ``note`` (:func:`stderr_notes`) says "not identifiable"."""
    v = np.asarray(value, float)
    se = np.broadcast_to(np.asarray(stderr, float), v.shape)
    with np.errstate(invalid="ignore"):
        big = np.isfinite(se) & (se > UNDETERMINED_REL_STDERR * np.abs(v))
    if note is not None:
        n = np.broadcast_to(np.asarray(note, object), v.shape)
        big = big | (n == STDERR_NOTES[2])
    return big


def entry_labels(name: str, shape, channels=()) -> list[str]:
    """Labels of a parameter's entries, flattened: ``name`` for a scalar, ``name[R]`` per channel
    when the size matches ``channels``, else ``name[j]``."""
    size = int(np.prod(shape)) if len(shape) else 1
    if not len(shape) or size == 1:
        return [name]
    if len(channels) == size:
        return [f"{name}[{c}]" for c in channels]
    return [f"{name}[{j}]" for j in range(size)]


def parameter_entries(params: dict, stderr: dict, channels=()):
    """``(name, j, label, value, standard error)`` for every entry of every parameter in
    ``params`` (flattened; ``label`` as :func:`entry_labels`), the standard error from
    ``stderr`` (NaN where undefined) or None where the parameter has none (a fixed one): the
    rows of the command line's and the report pages' parameter tables."""
    for name, value in params.items():
        v = np.asarray(value, float).reshape(-1)
        se = stderr.get(name)
        se = None if se is None else np.asarray(se, float).reshape(-1)
        for j, label in enumerate(entry_labels(name, np.shape(value), channels)):
            yield name, j, label, float(v[j]), None if se is None else float(se[j])


def stderr_notes(codes, shape=None) -> np.ndarray:
    """Codes (:func:`stderr_codes`, at-bound 1) -> an array of reasons ("" where defined)."""
    c = np.asarray(codes)
    out = np.full(c.shape, "", dtype=object)
    for k, why in STDERR_NOTES.items():
        out[c == k] = why
    return out if shape is None else out.reshape(shape)
