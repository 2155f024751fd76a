"""Plots of measured data against fitted models (matplotlib, an optional extra).

Every function returns a :class:`matplotlib.figure.Figure` built without ``pyplot`` (no global
figure state, no GUI backend, never shown): save it with ``fig.savefig(path)``. matplotlib is
imported inside the functions, so ``import brdf_fit.plot`` works without it; calling a function
without matplotlib raises ``ImportError``.

``models`` arguments are sequences of ``(label, model)`` pairs, ``model`` anything with
``eval(wi, wo)`` (a registry model, e.g. ``FitResult.model``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from brdf_fit.data import GonioData

__all__ = ["database_errors", "hemisphere", "in_plane_samples", "in_plane_slices",
           "model_lobes", "residuals", "rusinkiewicz_slice", "rusinkiewicz_slices",
           "selection_front", "table_maps"]

#: Tolerance on angles (degrees) when picking the in-plane samples out of a scattered dataset.
ANGLE_TOL_DEG = 0.5


def _figure(width: float, height: float):
    from matplotlib.figure import Figure  # lazy: matplotlib is optional

    return Figure(figsize=(width, height), layout="constrained")


def _channel(data: GonioData, channel) -> int:
    if channel is None:
        return 1 if data.n_channels == 3 else 0
    if isinstance(channel, str):
        if channel not in data.channels:
            raise ValueError(f"unknown channel {channel!r}; channels: {list(data.channels)}")
        return data.channels.index(channel)
    return int(channel)


def _eval(model, wi, wo) -> np.ndarray:
    """``model.eval`` as one compiled call (:func:`brdf_fit.models._base.evaluate`: shared by
    every model of one structure and shape, where a closure would compile once per model)."""
    import jax.numpy as jnp

    from brdf_fit.models._base import evaluate

    v = np.asarray(evaluate(model, jnp.asarray(wi), jnp.asarray(wo)), dtype=float)
    return v[:, None] if v.ndim == 1 else v


def in_plane_samples(data: GonioData, theta_i_deg: float, phi_i_deg: float = 0.0):
    """The samples of ``data`` in the plane of incidence at ``theta_i_deg`` (azimuth
    ``phi_i_deg``): ``(signed theta_o in degrees, index)``, sorted; positive ``theta_o`` on the
    specular side (``phi_o = phi_i + 180``), negative on the source side."""
    a = data.angles_deg()

    def near(x, y):
        return np.abs((x - y + 180.0) % 360.0 - 180.0) < ANGLE_TOL_DEG

    at_ti = np.abs(a["theta_i"] - theta_i_deg) < ANGLE_TOL_DEG
    if theta_i_deg > ANGLE_TOL_DEG:
        at_ti &= near(a["phi_i"], phi_i_deg)
    pole = a["theta_o"] < ANGLE_TOL_DEG
    fwd = near(a["phi_o"], phi_i_deg + 180.0) & ~pole
    back = near(a["phi_o"], phi_i_deg) & ~pole
    idx_f = np.flatnonzero(at_ti & fwd)
    idx_b = np.flatnonzero(at_ti & back)
    idx_p = np.flatnonzero(at_ti & pole)[:1]  # the pole is one state, maybe measured repeatedly
    theta = np.concatenate([a["theta_o"][idx_f], -a["theta_o"][idx_b], np.zeros(idx_p.size)])
    idx = np.concatenate([idx_f, idx_b, idx_p])
    order = np.argsort(theta, kind="stable")
    return theta[order], idx[order]


def _sweep(theta_i_deg: float, theta_o_deg: np.ndarray, phi_i_deg: float = 0.0):
    ti, pi_ = math.radians(theta_i_deg), math.radians(phi_i_deg)
    to = np.radians(np.abs(theta_o_deg))
    po = np.where(theta_o_deg >= 0, pi_ + math.pi, pi_)
    wi = np.broadcast_to([math.sin(ti) * math.cos(pi_), math.sin(ti) * math.sin(pi_),
                          math.cos(ti)], (theta_o_deg.size, 3))
    wo = np.stack([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)], -1)
    return np.ascontiguousarray(wi), wo


def in_plane_slices(
    data: GonioData,
    models: Sequence[tuple[str, object]],
    theta_i_deg: Sequence[float] = (0.0, 30.0, 60.0),
    channel=None,
    phi_i_deg: float = 0.0,
    n_curve: int = 361,
    title: str | None = None,
    paired: Sequence[tuple[str, object] | None] | None = None,
):
    """Measured BRDF (points) against each model (curves) in the plane of incidence, one panel
    per incidence angle, log scale; ``channel`` is a name or an index (default: G of RGB data,
    else the first). ``paired``: a second fit of each model (same order, ``None`` where there is
    none), drawn dashed in its model's colour, e.g. the same model fitted in another error."""
    c = _channel(data, channel)
    fig = _figure(4.0 * len(theta_i_deg), 3.6)
    axes = fig.subplots(1, len(theta_i_deg), squeeze=False)[0]
    sweep = np.linspace(-89.0, 89.0, n_curve)
    pairs = [_sweep(ti, sweep, phi_i_deg) for ti in theta_i_deg]
    wi_all = np.concatenate([p[0] for p in pairs])
    wo_all = np.concatenate([p[1] for p in pairs])
    if paired is not None and len(paired) != len(models):
        raise ValueError(f"paired: {len(paired)} entries for {len(models)} models")

    def curve(model):  # one evaluation per model over every panel's sweep
        f = _eval(model, wi_all, wo_all)
        return f[:, min(c, f.shape[1] - 1)].reshape(len(theta_i_deg), n_curve)

    curves = [curve(model) for _, model in models]
    seconds = [None if p is None else curve(p[1]) for p in (paired or [None] * len(models))]
    for k, (ax, ti) in enumerate(zip(axes, theta_i_deg, strict=True)):
        th, idx = in_plane_samples(data, ti, phi_i_deg)
        v = data.value[idx, c]
        pos = v > 0
        ax.semilogy(th[pos], v[pos], "o", color="k", ms=4, label="measured", zorder=5)
        for j, (label, _) in enumerate(models):
            f = curves[j][k]
            ok = f > 0
            # the first model (the best, in a ranked list) drawn wider, so it shows beneath
            (line,) = ax.semilogy(sweep[ok], f[ok], "-", lw=2.6 if j == 0 else 1.2, label=label)
            if seconds[j] is not None:
                g = seconds[j][k]
                ax.semilogy(sweep[g > 0], g[g > 0], "--", lw=1.2, color=line.get_color(),
                            label=paired[j][0])
        if pos.any():  # keep the axis on the measurements, not on a model's far tail
            ax.set_ylim(v[pos].min() / 10.0, v[pos].max() * 3.0)
        ax.axvline(ti, color="0.7", lw=0.8, ls=":")
        ax.set_xlabel("signed theta_o [deg] (+: specular side)")
        ax.set_title(f"theta_i = {ti:g} deg")
        ax.set_xlim(-90, 90)
    axes[0].set_ylabel(f"f_r [1/sr], channel {data.channels[c]}")
    axes[-1].legend(fontsize=7, loc="lower center")
    if title:
        fig.suptitle(title)
    return fig


def residuals(data: GonioData, models: Sequence[tuple[str, object]], title: str | None = None):
    """Per-sample log residuals ``ln(model/measured)`` against the half-vector angle, one panel
    per model, every channel; dashed lines at +-1 median relative sigma when the data have
    uncertainties. Under each panel, where the misfit is: the rms of the log ratio in each
    region of the geometry (:func:`brdf_fit.fitting.regions.residuals_by_region`, the numbers
    ``fit`` prints), each bar labelled with the model's mean reading there (``+5%``: the model
    reads 5% high), the largest in red."""
    from brdf_fit.fitting.regions import residuals_by_region

    h = data.wi + data.wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    th = np.degrees(np.arctan2(np.hypot(h[:, 0], h[:, 1]), h[:, 2]))
    used = data.weight > 0
    n = len(models)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig = _figure(4.0 * cols, 4.6 * rows)
    grid = fig.add_gridspec(2 * rows, cols, height_ratios=[3.0, 1.6] * rows)
    axes = [fig.add_subplot(grid[2 * (k // cols), k % cols]) for k in range(n)]
    bars = [fig.add_subplot(grid[2 * (k // cols) + 1, k % cols]) for k in range(n)]
    rel_sigma = None
    if data.sigma is not None:
        good = used & (data.value > 0)
        if good.any():
            rel_sigma = float(np.median(data.sigma[good] / data.value[good]))
    colours = ["tab:red", "tab:green", "tab:blue"] if data.n_channels == 3 else None
    keep = used.any(axis=1)  # the region summary reads the samples the fit used
    for k, (ax, bx, (label, model)) in enumerate(zip(axes, bars, models, strict=True)):
        m = np.broadcast_to(_eval(model, data.wi, data.wo), data.value.shape)
        for c in range(data.n_channels):
            ok = used[:, c] & (data.value[:, c] > 0) & (m[:, c] > 0)
            r = np.log(m[ok, c] / data.value[ok, c])
            ax.plot(th[ok], r, ".", ms=2, alpha=0.6,
                    color=None if colours is None else colours[c], label=data.channels[c])
        ax.axhline(0.0, color="k", lw=0.8)
        if rel_sigma is not None:
            for s in (-rel_sigma, rel_sigma):
                ax.axhline(s, color="0.5", lw=0.8, ls="--")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("theta_h [deg]")
        if k % cols == 0:
            ax.set_ylabel("ln(model / measured)")
        _region_bars(bx, residuals_by_region(model, data.wi[keep], data.wo[keep],
                                             data.value[keep]), first=k % cols == 0)
    # a fixed corner: matplotlib's "best" searches every point (slow for a MERL file's million,
    # and it warns)
    axes[0].legend(fontsize=7, markerscale=3, loc="upper right")
    if title:
        fig.suptitle(title)
    return fig


def _region_bars(ax, rows: list[dict], first: bool) -> None:
    """Bars of ``rms_log_ratio`` per region (rows of ``residuals_by_region``), the largest red,
    each labelled with its mean factor; an empty region is named and left without a bar."""
    names = [r["region"] for r in rows]
    rms = np.array([r["rms_log_ratio"] for r in rows], float)
    finite = np.isfinite(rms)
    worst = int(np.nanargmax(np.where(finite, rms, -np.inf))) if finite.any() else -1
    y = np.arange(len(rows))
    ax.barh(y[finite], rms[finite], color=["tab:red" if i == worst else "0.6"
                                           for i in np.flatnonzero(finite)])
    top = float(np.max(rms[finite])) if finite.any() else 1.0
    for i, r in enumerate(rows):
        text = (f"{100 * r['mean_factor']:+.2g}%  ({r['samples']:,})" if finite[i]
                else "no samples")
        ax.text((rms[i] if finite[i] else 0.0) + 0.02 * top, i, text, va="center", fontsize=6)
    ax.set_yticks(y, names if first else [""] * len(names), fontsize=7)
    ax.invert_yaxis()
    ax.set_xlim(0.0, 1.45 * top if top > 0 else 1.0)
    ax.tick_params(axis="x", labelsize=7)
    ax.set_xlabel("rms of ln(model / measured), by region", fontsize=7)


def rusinkiewicz_slices(table, models: Sequence[tuple[str, object]], phi_d_deg: float = 90.0,
                        channel: int = 1):
    """The arrays :func:`rusinkiewicz_slice` draws: ``(theta_h_deg, theta_d_deg, data,
    [(label, model values, ln(model / data)), ...])``, images ``[i_theta_h, i_theta_d]`` of
    ``channel`` at the ``phi_d`` bin holding ``phi_d_deg``; NaN where a bin is missing (or a
    value is not positive, in the log ratio). ``table``: a MERL table (3, 90, 90, 180) or its
    :class:`~brdf_fit.render.MerlTable`, whose bins are drawn, or other dense data with an
    ``eval(wi, wo)`` (an RGL material, :class:`~brdf_fit.render.RGLData`), evaluated at the
    same bins' centres."""
    from brdf_fit.io.merl import MERL_DIMS, merl_slice_centres

    i_pd = min(int(phi_d_deg / 180.0 * MERL_DIMS[2]), MERL_DIMS[2] - 1)
    wi, wo, theta_h, theta_d = merl_slice_centres(i_pd)
    table = getattr(table, "table", table)  # a MerlTable's bins
    if hasattr(table, "eval"):
        data = np.asarray(table.eval(wi.reshape(-1, 3), wo.reshape(-1, 3)), float)
        data = data[:, None] if data.ndim == 1 else data
        data = np.broadcast_to(data, (data.shape[0], 3))[:, channel].reshape(wi.shape[:-1])
        data = np.where((wi[..., 2] > 0) & (wo[..., 2] > 0), data, np.nan)
    else:
        table = np.asarray(table, float)
        if table.shape != (3, *MERL_DIMS):
            raise ValueError(f"rusinkiewicz_slice: a MERL table (3, 90, 90, 180), got "
                             f"{table.shape}")
        data = table[channel, :, :, i_pd]
        data = np.where(data < 0.0, np.nan, data)
    rows = []
    for label, model in models:
        m = _eval(model, wi.reshape(-1, 3), wo.reshape(-1, 3))
        m = np.broadcast_to(m, (m.shape[0], 3))[:, channel].reshape(data.shape)
        m = np.where((wi[..., 2] > 0) & (wo[..., 2] > 0), m, np.nan)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.where((data > 0) & (m > 0), np.log(m / data), np.nan)
        rows.append((label, m, ratio))
    return np.degrees(theta_h), np.degrees(theta_d), data, rows


def rusinkiewicz_slice(table, models: Sequence[tuple[str, object]], phi_d_deg: float = 90.0,
                       channel: int = 1, title: str | None = None):
    """The Rusinkiewicz image slice of dense data (a MERL table, :func:`brdf_fit.io.merl.
    read_merl_table`, or an RGL material: :func:`rusinkiewicz_slices`) beside each model:
    ``theta_d`` to the right, ``theta_h`` upward (the bins' centres, MERL's square-root
    spacing), at one ``phi_d`` bin (90 degrees by default: the slice where retro-reflection
    sits at small ``theta_d`` and grazing at large); the data
    and each model in log10 on one scale, and ``ln(model / data)`` on a symmetric diverging
    scale; ``channel`` 0, 1, 2 = R, G, B. Missing bins are blank. Rusinkiewicz (1998), sec. 3."""
    th, td, data, rows = rusinkiewicz_slices(table, models, phi_d_deg, channel)
    fig = _figure(3.4 * (1 + 2 * bool(rows)), 3.0 * max(1, len(rows)))
    axes = fig.subplots(max(1, len(rows)), 3 if rows else 1, squeeze=False)
    with np.errstate(invalid="ignore", divide="ignore"):
        logs = [np.log10(data)] + [np.log10(m) for _, m, _ in rows]
    finite = np.concatenate([v[np.isfinite(v)] for v in logs])
    lo, hi = (float(np.percentile(finite, 1)), float(np.max(finite))) if finite.size else (0, 1)
    rmax = max([float(np.nanmax(np.abs(r))) for _, _, r in rows if np.isfinite(r).any()]
               + [1e-6])

    def image(ax, v, **kw):
        im = ax.pcolormesh(td, th, v, shading="nearest", **kw)
        ax.set_xlabel("theta_d [deg]")
        ax.set_ylabel("theta_h [deg]")
        return im

    name = "RGB"[channel]
    for k in range(max(1, len(rows))):
        im = image(axes[k, 0], logs[0], vmin=lo, vmax=hi, cmap="magma")
        axes[k, 0].set_title(f"data ({name}), log10 f", fontsize=9)
        fig.colorbar(im, ax=axes[k, 0])
        if rows:
            label, _, ratio = rows[k]
            im = image(axes[k, 1], logs[k + 1], vmin=lo, vmax=hi, cmap="magma")
            axes[k, 1].set_title(f"{label}, log10 f", fontsize=9)
            fig.colorbar(im, ax=axes[k, 1])
            im = image(axes[k, 2], ratio, vmin=-rmax, vmax=rmax, cmap="RdBu_r")
            axes[k, 2].set_title(f"ln({label} / data)", fontsize=9)
            fig.colorbar(im, ax=axes[k, 2])
    fig.suptitle((title + ": " if title else "") + f"phi_d = {phi_d_deg:g} deg slice")
    return fig


def table_maps(table, title: str | None = None):
    """A 2-D lookup table (:class:`brdf_fit.core.table.Table`) as images, one per channel, axis 1
    (e.g. ``mu``) to the right and axis 0 (e.g. roughness) upwards, and, when the table's
    metadata has a per-texel ``error_estimate`` on a subgrid, that error map (log scale)."""
    from matplotlib.colors import LogNorm

    if len(table.axes) != 2:
        raise ValueError(f"table_maps draws 2-D tables; this one has {len(table.axes)} axes")
    values = np.asarray(table.values, dtype=np.float64)
    err = table.meta.get("error_estimate", {})
    has_err = "per_texel" in err
    n = len(table.channels) + has_err
    fig = _figure(3.6 * n, 3.3)
    axes = fig.subplots(1, n, squeeze=False).ravel()
    a0, a1 = table.axes
    extent = (a1.lo, a1.hi, a0.lo, a0.hi)
    for ax, (k, name) in zip(axes, enumerate(table.channels), strict=False):
        im = ax.imshow(values[..., k], origin="lower", extent=extent, aspect="auto",
                       cmap="viridis")
        fig.colorbar(im, ax=ax, shrink=0.85)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(a1.name)
        ax.set_ylabel(a0.name)
    if has_err:
        ax = axes[-1]
        e = np.maximum(np.asarray(err["per_texel"], dtype=np.float64), 1e-17)
        x = a1.nodes()[np.asarray(err["columns"])]
        y = a0.nodes()[np.asarray(err["rows"])]
        norm = LogNorm(vmin=max(e.min(), 1e-17), vmax=max(e.max(), 1e-16))
        pc = ax.pcolormesh(x, y, e, norm=norm, shading="nearest", cmap="magma")
        fig.colorbar(pc, ax=ax, shrink=0.85)
        ax.set_title(f"error estimate (max {err.get('max_abs', e.max()):.2g})", fontsize=9)
        ax.set_xlabel(a1.name)
        ax.set_ylabel(a0.name)
    if title:
        fig.suptitle(title)
    return fig


def _pick(f: np.ndarray, channel) -> np.ndarray:
    """One channel of ``(N, C)`` values: ``channel`` an index, or None (G of RGB, else the
    first)."""
    c = (1 if f.shape[1] == 3 else 0) if channel is None else int(channel)
    if not 0 <= c < f.shape[1]:
        raise ValueError(f"channel {c} out of range: the model has {f.shape[1]} channel(s)")
    return f[:, c]


def model_lobes(models: Sequence[tuple[str, object]], theta_i_deg: Sequence[float] = (0.0, 30.0,
                60.0), channel=None, n_curve: int = 361, title: str | None = None):
    """Polar in-plane lobes: the reflected radiance ``f cos(theta_o)`` for unit irradiance, one
    polar panel per incidence angle (the normal up, the light arriving from the left, the
    specular side on the right), one curve per model, each curve scaled to its own peak (the
    shapes compare; the legend gives each peak)."""
    fig = _figure(3.6 * len(theta_i_deg), 3.2 + 0.25 * len(models))
    sweep = np.linspace(-90.0, 90.0, n_curve)
    pairs = [_sweep(ti, sweep) for ti in theta_i_deg]
    wi_all = np.concatenate([p[0] for p in pairs])
    wo_all = np.concatenate([p[1] for p in pairs])
    cos_o = np.cos(np.radians(np.abs(sweep)))
    curves = [_pick(_eval(m, wi_all, wo_all), channel).reshape(len(theta_i_deg), n_curve)
              for _, m in models]
    for k, ti in enumerate(theta_i_deg):
        ax = fig.add_subplot(1, len(theta_i_deg), k + 1, projection="polar")
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)  # +theta_o (specular side) to the right
        ax.set_thetamin(-90)
        ax.set_thetamax(90)
        for (label, _), c in zip(models, curves, strict=True):
            r = np.maximum(np.nan_to_num(c[k] * cos_o), 0.0)
            peak = float(r.max())
            ax.plot(np.radians(sweep), r / (peak or 1.0), label=f"{label} (peak {peak:.3g})")
        ax.plot([math.radians(-ti)] * 2, [0, 1.05], color="0.5", lw=0.8, ls=":")
        ax.set_title(f"theta_i = {ti:g} deg", fontsize=9)
        ax.set_yticklabels([])
        ax.legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, 0.02))
    if title:
        fig.suptitle(title)
    return fig


def hemisphere(model, theta_i_deg: Sequence[float] = (0.0, 30.0, 60.0), channel=None,
               n: int = 161, log: bool = True, title: str | None = None):
    """``f cos(theta_o)`` over the whole hemisphere of outgoing directions, one panel per
    incidence angle (light in the x-z plane, from -x), in the orthographic projection
    ``(x, y) = sin(theta_o) (cos phi_o, sin phi_o)`` (the unit disk seen from above); log colour
    scale by default."""
    from matplotlib.colors import LogNorm

    g = np.linspace(-1.0, 1.0, n)
    x, y = np.meshgrid(g, g)
    inside = x * x + y * y < 1.0
    z = np.sqrt(np.clip(1.0 - x * x - y * y, 0.0, 1.0))
    wo = np.stack([x[inside], y[inside], z[inside]], -1)
    fig = _figure(3.6 * len(theta_i_deg), 3.3)
    axes = fig.subplots(1, len(theta_i_deg), squeeze=False)[0]
    for ax, ti in zip(axes, theta_i_deg, strict=True):
        t = math.radians(ti)
        wi = np.broadcast_to([-math.sin(t), 0.0, math.cos(t)], wo.shape)
        img = np.full(x.shape, np.nan)
        img[inside] = _pick(_eval(model, np.ascontiguousarray(wi), wo), channel) * wo[:, 2]
        pos = img[np.isfinite(img) & (img > 0)]
        norm = (LogNorm(vmin=max(pos.max() * 1e-4, pos.min()), vmax=pos.max())
                if log and pos.size else None)
        im = ax.imshow(np.where(img > 0, img, np.nan) if log else img, origin="lower",
                       extent=(-1, 1, -1, 1), norm=norm, cmap="inferno")
        ax.add_patch(_circle()((0, 0), 1.0, fill=False, lw=0.8, color="0.5"))
        ax.set_title(f"theta_i = {ti:g} deg", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, shrink=0.85, label="f cos(theta_o)")
    if title:
        fig.suptitle(title)
    return fig


def _circle():
    from matplotlib.patches import Circle

    return Circle


def selection_front(selection, title: str | None = None):
    """Error against evaluation cost of every candidate of a
    :class:`brdf_fit.selection.Selection`: the budget line, the Pareto front joined, the choice
    ringed (log-log)."""
    fig = _figure(6.0, 4.2)
    ax = fig.subplots()
    cands = [c for c in selection.candidates if not c.message]  # failed fits have no point
    for c in cands:
        colour = "tab:green" if c.within_budget else "tab:red"
        ax.loglog(c.cost_ns, max(c.error, 1e-12), "o", color=colour)
        ax.annotate(c.model, (c.cost_ns, max(c.error, 1e-12)), fontsize=7, xytext=(4, 3),
                    textcoords="offset points")
    front = sorted((c for c in cands if c.pareto), key=lambda c: c.cost_ns)
    ax.plot([c.cost_ns for c in front], [max(c.error, 1e-12) for c in front], "-", color="0.6",
            lw=0.8, label="Pareto front")
    ax.axhline(selection.budget, color="k", ls="--", lw=0.8,
               label=f"budget {selection.budget:.3g}")
    if selection.choice is not None:
        ch = selection.candidate(selection.choice)
        ax.loglog(ch.cost_ns, max(ch.error, 1e-12), "o", ms=14, mfc="none", color="k",
                  label=f"choice: {ch.model}")
    ax.set_xlabel("cost [ns per evaluation, jit, this machine]")
    ax.set_ylabel("relative RMS radiance error")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", lw=0.3)
    if title:
        ax.set_title(title, fontsize=9)
    return fig


def scene_front(result, title: str | None = None):
    """A scene's selection (:class:`brdf_fit.selection.scene.SceneSelection`): one row per
    material, the radiance error of every fitted candidate (dots, by measured cost, left to
    right), the material's budget (tick) and the scene's choice (ringed); the model set in the
    title line. Errors below 1e-4 (a formula material fitted by itself: 1e-16) are drawn at
    1e-4."""
    mats = result.materials
    fig = _figure(7.5, 0.9 + 0.42 * len(mats))
    ax = fig.subplots()
    floor = 1e-4
    models = sorted({c.model for m in mats for c in m.selection.candidates if not c.message},
                    key=lambda n: (result.costs.get(n, math.inf), n))
    colours = {n: f"C{i % 10}" for i, n in enumerate(models)}
    for row, m in enumerate(mats):
        for c in m.selection.candidates:
            if c.message:
                continue
            ax.semilogx(max(c.error, floor), row, "o", ms=5, color=colours[c.model], alpha=0.8)
        ax.plot([m.selection.budget] * 2, [row - 0.35, row + 0.35], "k-", lw=1.0)
        ax.semilogx(max(m.error, floor), row, "o", ms=12, mfc="none", color="k")
    for n in models:
        cost = result.costs.get(n, math.nan)
        ax.plot([], [], "o", color=colours[n], label=f"{n} ({cost:.3g} ns)")
    ax.plot([], [], "o", ms=10, mfc="none", color="k", label="scene's choice")
    ax.plot([], [], "k|", ms=10, mew=1.0, ls="none", label="budget")
    ax.set_yticks(range(len(mats)), [m.material.name for m in mats], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("relative RMS radiance error (below 1e-4 drawn at 1e-4)")
    ax.grid(True, which="both", axis="x", lw=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    head = (f"model set: {', '.join(result.model_set)} ({result.cost_ns_total:.3g} ns in all, "
            f"worst error {result.worst_error:.3g})")
    ax.set_title(head if not title else f"{title}\n{head}", fontsize=9)
    return fig


def database_errors(rows: Sequence[dict], measure: str = "rel_rms", title: str | None = None):
    """A database run's errors (:func:`brdf_fit.fitting.database.fit_database` rows): one line
    per model over the materials, the materials ordered by the error of the best model for each
    (as Ngan et al., EGSR 2005, plot theirs), the error on a log scale; a fit that did not
    converge is drawn as an open marker."""
    models = list(dict.fromkeys(r["model"] for r in rows))
    materials = list(dict.fromkeys(r["material"] for r in rows))
    err = {(r["material"], r["model"]): r for r in rows}

    def best(m):
        vals = [err[(m, k)]["errors"][measure] for k in models if (m, k) in err]
        vals = [v for v in vals if v is not None and math.isfinite(v)]
        return min(vals) if vals else math.inf

    order = sorted(materials, key=best)
    fig = _figure(max(6.0, 0.28 * len(order) + 2.5), 4.2)
    ax = fig.add_subplot()
    x = np.arange(len(order))
    for k in models:
        xs, ys, conv = [], [], []
        for i, m in enumerate(order):
            r = err.get((m, k))
            v = None if r is None else r["errors"][measure]
            if v is not None and math.isfinite(v) and v > 0:
                xs.append(i)
                ys.append(v)
                conv.append(bool(r["converged"]))
        line, = ax.plot(xs, ys, "-", lw=1, label=k)
        c = line.get_color()
        ax.plot([a for a, ok in zip(xs, conv, strict=True) if ok],
                [b for b, ok in zip(ys, conv, strict=True) if ok], "o", ms=4, color=c)
        ax.plot([a for a, ok in zip(xs, conv, strict=True) if not ok],
                [b for b, ok in zip(ys, conv, strict=True) if not ok], "o", ms=5, mfc="none",
                color=c)
    ax.set_yscale("log")
    ax.set_xticks(x, order, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel(measure)
    ax.set_xlabel("material (ordered by its best model's error)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(title or f"{len(order)} materials x {len(models)} models: {measure} "
                 "(open marker: not converged)", fontsize=9)
    return fig


def database_front_points(rows: Sequence[dict], measure: str = "rel_rms",
                          costs: dict | None = None) -> list[dict]:
    """Speed against error over a database run's materials: per model with a committed cost
    (``costs``, default :func:`brdf_fit.selection.costs.committed_costs`, x Lambert), its
    finite positive errors over the materials, their median, and whether that median is on the
    Pareto front of the models (no other model both no dearer and no worse, and one of them
    strictly), as :func:`brdf_fit.selection.Selection`'s candidates are for one material."""
    from brdf_fit.selection.costs import committed_costs

    costs = committed_costs() if costs is None else costs
    points = []
    for k in dict.fromkeys(r["model"] for r in rows):
        errs = [r["errors"].get(measure) for r in rows if r["model"] == k]
        errs = [float(v) for v in errs if v is not None and math.isfinite(v) and v > 0]
        if k in costs and errs:
            points.append({"model": k, "cost": float(costs[k]), "errors": errs,
                           "median": float(np.median(errs))})
    for p in points:
        p["pareto"] = not any(
            o["cost"] <= p["cost"] and o["median"] <= p["median"]
            and (o["cost"] < p["cost"] or o["median"] < p["median"])
            for o in points if o is not p)
    return points


def database_front(rows: Sequence[dict], measure: str = "rel_rms", costs: dict | None = None,
                   title: str | None = None):
    """:func:`database_front_points` drawn (log-log): each model's error on every material
    (small points) and their median (large), at its committed cost; the Pareto front of the
    medians joined."""
    points = database_front_points(rows, measure, costs)
    fig = _figure(6.0, 4.2)
    ax = fig.subplots()
    for p in points:
        line, = ax.loglog([p["cost"]] * len(p["errors"]), p["errors"], ".", ms=4, alpha=0.5)
        ax.loglog(p["cost"], p["median"], "o", ms=8, color=line.get_color())
        ax.annotate(p["model"], (p["cost"], p["median"]), fontsize=7, xytext=(5, 3),
                    textcoords="offset points")
    front = sorted((p for p in points if p["pareto"]), key=lambda p: p["cost"])
    ax.plot([p["cost"] for p in front], [p["median"] for p in front], "-", color="0.4", lw=0.8,
            label="Pareto front of the medians")
    ax.set_xlabel("cost [x Lambert, committed table]")
    ax.set_ylabel(f"{measure} (each material; large: median)")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)
    ax.set_title(title or "speed against error over the materials", fontsize=9)
    return fig
