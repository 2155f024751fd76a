"""Self-contained HTML pages (issue 46). For a fit (``brdf-fit fit --report out.html``): the
parameters with their 95% intervals, where the misfit is, the fit rendered (and dense data
rendered from themselves beside it, with FLIP between the two), the data against the fit as
slices, and the command and version that produced it. For a selection (``brdf-fit select
--report out.html``): the choice and why, every candidate's error and cost, speed against error
as a picture with the Pareto front, the chosen and the most accurate candidates rendered and
against the data, the exports. For a database run (``brdf-fit fit FILES --model A,B --table
T.csv --report out.html``): the error of every model on every material, as a table and as Ngan
et al.'s figure, each material's best fit rendered, the failures and the options.

Every figure is a PNG inside the page (``data:`` URIs), so the file opens anywhere without the
network; the page has no script and reads as plain HTML (inline CSS for the tables only).
"""

from __future__ import annotations

import base64
import datetime
import html
import io
import math
import platform

import numpy as np

from brdf_fit._version import __version__

__all__ = ["REPORT_SPHERE_SIZE", "database_report", "fit_report", "select_report"]

#: side in pixels of the rendered spheres in a report
REPORT_SPHERE_SIZE = 256
#: the normal quantile of a two-sided 95% interval
Z95 = 1.959963984540054

_STYLE = """
body { font-family: sans-serif; max-width: 1100px; margin: 1.5em auto; padding: 0 1em;
       color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
img { max-width: 100%; }
figure { display: inline-block; margin: 0.5em 1em 0.5em 0; vertical-align: top; }
figcaption { font-size: 0.85em; color: #555; max-width: 520px; }
code, pre { background: #f4f4f4; }
.bad { color: #a00; font-weight: bold; }
"""


def _png_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _figure_png(figure) -> bytes:
    buf = io.BytesIO()
    figure.savefig(buf, format="png", dpi=100)
    return buf.getvalue()


def _pixels_png(pixels) -> bytes:
    import matplotlib.image

    buf = io.BytesIO()
    matplotlib.image.imsave(buf, pixels, format="png")
    return buf.getvalue()


def _img(png: bytes, alt: str, caption: str) -> str:
    return (f'<figure><img src="{_png_uri(png)}" alt="{html.escape(alt)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _num(x, digits: int = 6) -> str:
    x = float(x)
    return "n/a" if not np.isfinite(x) else f"{x:.{digits}g}"


def _interval_cells(x, se) -> list[str]:
    """The standard error and 95% interval cells of an entry (``se`` None or NaN: none)."""
    if se is None or not np.isfinite(se):
        return ["undefined", ""]
    return [_num(se, 3), f"[{_num(x - Z95 * se)}, {_num(x + Z95 * se)}]"]


def _row(label: str, x, cells: list[str], note: str) -> str:
    cls = ' class="bad"' if note else ""
    return (f"<tr><td>{html.escape(label)}</td><td>{_num(x)}</td><td>{cells[0]}</td>"
            f"<td>{cells[1]}</td><td{cls}>{html.escape(note)}</td></tr>")


def _parameter_rows(result, channels) -> list[str]:
    from brdf_fit.fitting.problem import parameter_entries  # (JAX: not at the page's import)

    rows = []
    flagged = set(result.undetermined)
    for name, j, label, x, se in parameter_entries(result.params, result.stderr, channels):
        if name in result.fixed:
            cells, note = ["fixed", ""], ""
        else:
            cells = _interval_cells(x, se)
            note = ("no standard error" if cells[0] == "undefined" else
                    "undetermined" if label in flagged else "")
        # per entry: a vector with one channel at its bound flags that channel only
        notes = result.stderr_note.get(name)
        entry_note = "" if notes is None else str(np.ravel(np.asarray(notes))[j])
        if name in result.at_bound and (notes is None or entry_note == "at bound"):
            note = (note + "; " if note else "") + "at an interval end"
        rows.append(_row(label, x, cells, note))
    return rows


def _region_rows(regions) -> list[str]:
    rms = [r["rms_log_ratio"] for r in regions]
    worst = int(np.nanargmax(rms)) if np.isfinite(rms).any() else -1
    rows = []
    for k, r in enumerate(regions):
        mark = ' class="bad"' if k == worst else ""
        rows.append(f"<tr><td{mark}>{html.escape(r['region'])}</td><td>{r['samples']}</td>"
                    f"<td>{100 * r['share']:.1f}%</td><td>{_num(r['rms_log_ratio'], 3)}</td>"
                    f"<td>{100 * r['mean_factor']:+.2f}%</td></tr>")
    return rows


def fit_report(result, data, *, source: str, command: str, table=None,
               export: dict | None = None) -> str:
    """The HTML page of ``result`` (:class:`~brdf_fit.fitting.single.FitResult`) fitted to
    ``data`` (:class:`~brdf_fit.data.GonioData`) read from ``source``. ``table``: the data as
    dense data when they are (:func:`brdf_fit.render.dense_data`: a MERL table or an RGL
    material; a bare MERL table array is taken too): they are then rendered from themselves
    beside the fit, with FLIP between the two (where ``flip-evaluator`` is installed), and
    their Rusinkiewicz slice is drawn. ``export``: the
    fit's ``--export`` answer, shown as written. ``command``: the command line, shown as
    given."""

    regions = result.regions if result.regions is not None else result.residuals_by_region(data)
    label = f"{result.model_name} (fit)"
    parts = []
    flip_line, figures = _rendered([(result.model_name, result.model)], table)
    slices = _slices(data, [(label, result.model)], table)

    status = ("converged" if result.converged
              else f'<span class="bad">not converged</span>: {html.escape(result.message)}')
    parts.append(f"<h1>{html.escape(result.model_name)} fitted to "
                 f"{html.escape(source)}</h1>")
    parts.append(f"<p>{result.n_samples} samples x {data.n_channels} channel(s) "
                 f"({html.escape(', '.join(data.channels))}), metric {html.escape(result.metric)}"
                 f"; {status} in {result.steps} steps ({result.starts} start(s)); residual rms "
                 f"{_num(result.residual_rms, 4)}; {result.seconds:.2f} s.</p>")
    parts.append("<h2>Parameters</h2><table><tr><th>parameter</th><th>value</th>"
                 "<th>standard error</th><th>95% interval</th><th>note</th></tr>"
                 + "".join(_parameter_rows(result, tuple(data.channels))) + "</table>")
    pairs = result.strongly_correlated()
    if pairs:
        parts.append("<p>Strongly correlated (the data determine a combination better than "
                     "either): " + html.escape(", ".join(f"{a} ~ {b} ({r:+.4f})"
                                                          for a, b, r in pairs)) + "</p>")
    parts.append("<h2>Where the misfit is</h2><p>ln(fit / data) by region of the geometry "
                 "(brdf_fit.fitting.regions); the largest rms in red.</p><table><tr>"
                 "<th>region</th><th>samples</th><th>share</th><th>rms</th>"
                 "<th>mean (fit vs data)</th></tr>" + "".join(_region_rows(regions))
                 + "</table>")
    parts.append("<h2>Rendered</h2>" + flip_line + "".join(figures))
    parts.append("<h2>Data and fit</h2>" + "".join(slices))
    if export is not None:
        parts.append("<h2>Export</h2><p>" + html.escape(
            f"{export.get('target')} ({export.get('method')}): {export.get('note')}; written "
            f"to {export.get('path', '')}") + "</p>")
        if export.get("text"):
            parts.append(f"<pre>{html.escape(export['text'])}</pre>")
    return _page(f"{result.model_name}: {source}", parts, command)


def _rendered(models, table) -> tuple[str, list[str]]:
    """``(FLIP line, figures)``: each ``(name, model)`` rendered as a sphere; for dense data
    (``table``: MERL or RGL) the data rendered from themselves first, and FLIP from the data to the
    first model."""
    from brdf_fit import render

    spheres = [render.render_sphere(m, REPORT_SPHERE_SIZE) for _, m in models]
    figures = [_img(_pixels_png(render.srgb_8bit(sp.radiance)), f"{name}, rendered",
                    f"{name} as fitted: a sphere under a directional light at 45 degrees, "
                    "irradiance pi, sRGB, exposure 0 (brdf-fit render)")
               for (name, _), sp in zip(models, spheres, strict=True)]
    flip_line = ""
    if table is not None:
        shader = table if hasattr(table, "eval") else render.MerlTable(table)
        measured = render.render_sphere(shader, REPORT_SPHERE_SIZE)
        figures.insert(0, _img(_pixels_png(render.srgb_8bit(measured.radiance)),
                               "the data, rendered",
                               "the data rendered from themselves (trilinear between the MERL "
                               "bin centres), the same light"))
        try:
            emap, mean = render.flip_error(measured, spheres[0])
            figures.append(_img(_pixels_png(render.error_map_8bit(emap)), "FLIP error map",
                                f"NVIDIA FLIP, data to {models[0][0]} (magma: black 0, yellow "
                                f"1); mean over the sphere {mean:.4g}"))
            flip_line = (f"<p>FLIP between the data and {html.escape(models[0][0])}, mean over "
                         f"the sphere: <b>{mean:.4g}</b> (0 identical; below 0.01 hard to tell "
                         "apart).</p>")
        except ImportError as e:
            flip_line = f"<p>No FLIP difference: {html.escape(str(e))}.</p>"
    else:
        figures.append("<p>Sparse data (a gonioreflectometer file) cannot be rendered from "
                       "themselves: only the fit is.</p>")
    return flip_line, figures


def _slices(data, models, table) -> list[str]:
    """In-plane slices and residuals of the data against ``models`` (``(label, model)``); the
    Rusinkiewicz slice for dense data (``table``: MERL or RGL)."""
    from brdf_fit import plot

    out = [_img(_figure_png(plot.in_plane_slices(data, models, (0.0, 30.0, 60.0))),
                "in-plane slices", "data and fit in the plane of incidence"),
           _img(_figure_png(plot.residuals(data, models)),
                "residuals", "ln(fit / data) per sample against the half-vector angle")]
    if table is not None:
        out.append(_img(_figure_png(plot.rusinkiewicz_slice(table, models)),
                        "Rusinkiewicz slice",
                        "the phi_d = 90 degree slice of data and fit, and their log ratio"))
    return out


def _page(title: str, parts: list[str], command: str) -> str:
    """The whole document: ``parts`` and the provenance (command, version, machine, time)."""
    when = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    parts = [*parts, f"<h2>Provenance</h2><p><code>{html.escape(command)}</code></p><p>"
             f"brdf_fit {html.escape(__version__)}, Python {platform.python_version()}, "
             f"{html.escape(platform.platform())}, {when}.</p>"]
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>\n"
            + "\n".join(parts) + "\n</body></html>\n")


def _candidate_parameter_rows(c, channels) -> list[str]:
    """Value, standard error and 95% interval of a selection candidate's parameters."""
    from brdf_fit.fitting.problem import parameter_entries

    return [_row(label, x, _interval_cells(x, se),
                 "undetermined" if name in c.undetermined or label in c.undetermined else "")
            for name, _, label, x, se in parameter_entries(c.params, c.stderr, channels)]


def _candidate_rows(selection) -> list[str]:
    rows = []
    for c in sorted(selection.candidates, key=lambda c: (bool(c.message), c.cost_ns)):
        if c.message:
            rows.append(f"<tr><td>{html.escape(c.model)}</td><td colspan=\"7\" "
                        f"class=\"bad\">{html.escape(c.message)}</td></tr>")
            continue
        mark = " <b>(choice)</b>" if c.model == selection.choice else ""
        gain = ""
        if c.lobe_gain:
            g = c.lobe_gain
            gain = (f"{100 * g['fraction_removed']:.1f}% of {html.escape(g['base'])}'s error"
                    + ("" if "supported" not in g else
                       ("; lobe supported" if g["supported"] else "; lobe not supported")))
        cost = "n/a" if c.cost_rel is None else f"{c.cost_rel:.3g}"
        within = "yes" if c.within_budget else '<span class="bad">no</span>'
        conv = "yes" if c.converged else '<span class="bad">no</span>'
        rows.append(f"<tr><td>{html.escape(c.model)}{mark}</td><td>{_num(c.error, 4)}</td>"
                    f"<td>{within}</td><td>{cost}</td><td>{_num(c.cost_ns, 3)}</td>"
                    f"<td>{'yes' if c.pareto else ''}</td><td>{conv}</td><td>{gain}</td></tr>")
    return rows


#: candidates drawn against the data besides the choice: the most accurate ones
SELECT_REPORT_MODELS = 3


def select_report(selection, data, *, source: str, command: str, table=None,
                  exports=()) -> str:
    """The HTML page of ``selection`` (:class:`~brdf_fit.selection.Selection`) made from
    ``data`` read from ``source``: the choice and the rules that made it, every candidate
    (error, within the budget, committed and live cost, on the Pareto front, converged, what
    an extra lobe removes), error against cost with the front and the choice ringed, the
    choice's parameters with their 95% intervals, the choice and the most accurate candidates
    rendered (dense data, ``table``: the data too, with FLIP to the choice) and against
    the data. ``exports``: the command's written exports (their ``to_dict`` answers)."""
    from brdf_fit import plot

    fitted = sorted((c for c in selection.candidates if not c.message and c.fitted is not None),
                    key=lambda c: c.error)
    shown = ([selection.candidate(selection.choice)] if selection.choice is not None else [])
    shown += [c for c in fitted if c not in shown][:SELECT_REPORT_MODELS - len(shown)]
    parts = [f"<h1>Model selection for {html.escape(source)}</h1>"]
    parts.append(f"<p>{data.n} samples x {data.n_channels} channel(s) "
                 f"({html.escape(', '.join(data.channels))}). Error: "
                 f"{html.escape(selection.error_definition)}. Budget {_num(selection.budget, 4)}"
                 f" ({html.escape(selection.budget_rule)}). Cost: "
                 f"{html.escape(selection.cost_rule)}."
                 + (f" Target: {html.escape(selection.target)} (every candidate is written to "
                    "it as fitted)." if selection.target else "") + "</p>")
    if selection.choice is None:
        parts.append(f'<p class="bad">{html.escape(selection.message)}</p>')
    else:
        parts.append(f"<p><b>Choice: {html.escape(selection.choice)}</b>. "
                     f"{html.escape(selection.message)}</p>")
    parts.append("<h2>Candidates</h2><table><tr><th>model</th><th>error</th>"
                 "<th>within budget</th><th>cost (x Lambert)</th><th>ns per evaluation</th>"
                 "<th>Pareto front</th><th>converged</th><th>extra lobe removes</th></tr>"
                 + "".join(_candidate_rows(selection)) + "</table>")
    parts.append("<h2>Speed against error</h2>" + _img(
        _figure_png(plot.selection_front(selection, title=source)), "speed against error",
        "relative RMS radiance error against evaluation cost; the Pareto front joined, the "
        "budget dashed, the choice ringed"))
    if selection.choice is not None:
        c = selection.candidate(selection.choice)
        parts.append("<h2>The choice's parameters</h2><table><tr><th>parameter</th>"
                     "<th>value</th><th>standard error</th><th>95% interval</th><th>note</th>"
                     "</tr>" + "".join(_candidate_parameter_rows(c, tuple(data.channels)))
                     + "</table>")
    if shown:
        models = [(c.model, c.fitted) for c in shown]
        flip_line, figures = _rendered(models, table)
        parts.append("<h2>Rendered</h2>" + flip_line + "".join(figures))
        parts.append("<h2>Data and candidates</h2>" + "".join(_slices(data, models, table)))
    if exports:
        parts.append("<h2>Exports</h2><ul>" + "".join(
            "<li>" + html.escape(f"{e.get('target')} ({e.get('method')}): written to "
                                 f"{e.get('path')}" + ("" if e.get("error") is None else
                                                       f"; round-trip error {e['error']:.3g}"))
            + "</li>" for e in exports) + "</ul>")
    return _page(f"selection: {source}", parts, command)


#: side in pixels of each material's sphere on a database run's page
DATABASE_SPHERE_SIZE = 128


def _row_model(row):
    """The fitted model of a database row (its parameters by entry label, ``f0[R]`` ...,
    gathered back into arrays in the row's order), or None where the entry no longer builds."""
    from brdf_fit import registry

    params: dict = {}
    for label, v in row["params"].items():
        params.setdefault(label.split("[", 1)[0], []).append(v)
    try:
        return registry.get(row["model"]).build(
            **{k: np.array(v) if len(v) > 1 else np.array(v[0]) for k, v in params.items()})
    except (KeyError, ValueError, TypeError):
        return None


def database_report(rows, meta: dict, *, table: str, command: str) -> str:
    """The HTML page of a database run (:func:`brdf_fit.fitting.database.fit_database` rows and
    the table's ``meta``: files, models, options, failures) written to ``table``: every model's
    relative RMS radiance error on every material (the best per material in bold, a fit that
    did not converge marked), the same as Ngan et al.'s figure (materials ordered by their best
    error), each material's best fit rendered, the published measures of that fit, the
    failures and the options."""
    from brdf_fit import plot, render
    from brdf_fit.fitting.errors import ERRORS

    models = list(meta.get("models") or dict.fromkeys(r["model"] for r in rows))
    materials = list(dict.fromkeys(r["material"] for r in rows))
    by = {(r["material"], r["model"]): r for r in rows}

    def rel(r):
        v = r["errors"].get("rel_rms")
        return math.inf if v is None or not math.isfinite(v) else v

    best = {m: min((by[(m, k)] for k in models if (m, k) in by), key=rel) for m in materials}
    parts = [f"<h1>Database fit: {len(meta.get('files', materials))} files x {len(models)} "
             f"models</h1>",
             f"<p>Table: {html.escape(table)} (CSV, and JSON beside it). {len(rows)} of "
             f"{meta.get('pairs', len(rows))} pairs finished; options: "
             f"{html.escape(', '.join(f'{k}={v}' for k, v in (meta.get('options') or {}).items()))}"
             ".</p>"]
    failures = meta.get("failures") or []
    if failures:
        parts.append('<p class="bad">Failed: ' + html.escape("; ".join(map(str, failures)))
                     + "</p>")
    head = "".join(f"<th>{html.escape(k)}</th>" for k in models)
    body = []
    for m in materials:
        cells = []
        for k in models:
            r = by.get((m, k))
            if r is None:
                cells.append("<td>-</td>")
                continue
            txt = _num(r["errors"].get("rel_rms", math.nan), 4) + (
                "" if r["converged"] else " (not converged)")
            cells.append(f"<td><b>{txt}</b></td>" if r is best[m] else f"<td>{txt}</td>")
        body.append(f"<tr><td>{html.escape(m)}</td>{''.join(cells)}</tr>")
    parts.append("<h2>Relative RMS radiance error</h2><p>" + html.escape(ERRORS["rel_rms"])
                 + "; the best model per material in bold.</p><table><tr><th>material</th>"
                 + head + "</tr>" + "".join(body) + "</table>")
    parts.append(_img(_figure_png(plot.database_errors(rows)), "errors over the materials",
                      "each model's error over the materials, ordered by their best error "
                      "(as Ngan et al., EGSR 2005, plot theirs); open markers: not converged"))
    parts.append("<h2>Speed against error</h2>" + _img(
        _figure_png(plot.database_front(rows)), "speed against error over the materials",
        "each model's error on every material (small points) and their median (large) against "
        "its committed evaluation cost (x Lambert); the Pareto front of the medians joined"))
    measures = [k for k in ERRORS if k != "rel_rms"]
    rows_best = "".join(
        f"<tr><td>{html.escape(m)}</td><td>{html.escape(best[m]['model'])}</td>"
        + "".join(f"<td>{_num(best[m]['errors'].get(k, math.nan), 4)}</td>" for k in measures)
        + "</tr>" for m in materials)
    parts.append("<h2>The best fit per material, in the published measures</h2><table><tr>"
                 "<th>material</th><th>model</th>"
                 + "".join(f"<th>{html.escape(k)}</th>" for k in measures) + "</tr>"
                 + rows_best + "</table><p>"
                 + "<br>".join(html.escape(f"{k}: {ERRORS[k]}") for k in measures) + "</p>")
    figures = []
    for m in materials:
        model = _row_model(best[m])
        if model is None:
            continue
        sphere = render.render_sphere(model, DATABASE_SPHERE_SIZE)
        figures.append(_img(_pixels_png(render.srgb_8bit(sphere.radiance)), f"{m}, rendered",
                            f"{m}: {best[m]['model']} as fitted (directional light at 45 "
                            "degrees, irradiance pi, sRGB)"))
    parts.append("<h2>Each material's best fit, rendered</h2>" + "".join(figures))
    return _page(f"database fit: {table}", parts, command)
