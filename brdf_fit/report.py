"""One self-contained HTML page for a fit (``brdf-fit fit --report out.html``, issue 46): the
parameters with their 95% intervals, where the misfit is, the fit rendered (and dense data
rendered from themselves beside it, with FLIP between the two), the data against the fit as
slices, and the command and version that produced it.

Every figure is a PNG inside the page (``data:`` URIs), so the file opens anywhere without the
network; the page has no script and reads as plain HTML (inline CSS for the tables only).
"""

from __future__ import annotations

import base64
import datetime
import html
import io
import platform

import numpy as np

from brdf_fit._version import __version__

__all__ = ["REPORT_SPHERE_SIZE", "fit_report"]

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


def _parameter_rows(result, channels) -> list[str]:
    rows = []
    flagged = set(result.undetermined)
    for name, value in result.params.items():
        v = np.atleast_1d(np.asarray(value, float))
        se = result.stderr.get(name)
        se = None if se is None else np.atleast_1d(np.asarray(se, float))
        for j, x in enumerate(v):
            label = name if v.size == 1 else (
                f"{name}[{channels[j]}]" if len(channels) == v.size else f"{name}[{j}]")
            if name in result.fixed:
                cells = ["fixed", "", ""]
            elif se is None or not np.isfinite(se[j]):
                cells = ["undefined", "", "no standard error"]
            else:
                cells = [_num(se[j], 3), f"[{_num(x - Z95 * se[j])}, {_num(x + Z95 * se[j])}]",
                         "undetermined" if label in flagged else ""]
            if name in result.at_bound:
                cells[2] = (cells[2] + "; " if cells[2] else "") + "at an interval end"
            cls = ' class="bad"' if cells[2] else ""
            rows.append(f"<tr><td>{html.escape(label)}</td><td>{_num(x)}</td>"
                        f"<td>{cells[0]}</td><td>{cells[1]}</td>"
                        f"<td{cls}>{html.escape(cells[2])}</td></tr>")
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
    ``data`` (:class:`~brdf_fit.data.GonioData`) read from ``source``. ``table``: the dense
    MERL table of the data (:func:`brdf_fit.io.merl.read_merl_table`) when they are one:
    they are then rendered from themselves beside the fit, with FLIP between the two (where
    ``flip-evaluator`` is installed), and their Rusinkiewicz slice is drawn. ``export``: the
    fit's ``--export`` answer, shown as written. ``command``: the command line, shown as
    given."""
    from brdf_fit import plot, render

    regions = result.regions if result.regions is not None else result.residuals_by_region(data)
    label = f"{result.model_name} (fit)"
    parts = []
    sphere = render.render_sphere(result.model, REPORT_SPHERE_SIZE)
    figures = [_img(_pixels_png(render.srgb_8bit(sphere.radiance)), "the fit, rendered",
                    f"{result.model_name} as fitted: a sphere under a directional light at 45 "
                    "degrees, irradiance pi, sRGB, exposure 0 (brdf-fit render)")]
    flip_line = ""
    if table is not None:
        measured = render.render_sphere(render.MerlTable(table), REPORT_SPHERE_SIZE)
        figures.insert(0, _img(_pixels_png(render.srgb_8bit(measured.radiance)),
                               "the data, rendered",
                               "the data rendered from themselves (trilinear between the MERL "
                               "bin centres), the same light"))
        try:
            emap, mean = render.flip_error(measured, sphere)
            figures.append(_img(_pixels_png(render.error_map_8bit(emap)), "FLIP error map",
                                f"NVIDIA FLIP, data to fit (magma: black 0, yellow 1); mean "
                                f"over the sphere {mean:.4g}"))
            flip_line = f"<p>FLIP between the data and the fit, mean over the sphere: " \
                        f"<b>{mean:.4g}</b> (0 identical; below 0.01 hard to tell apart).</p>"
        except ImportError as e:
            flip_line = f"<p>No FLIP difference: {html.escape(str(e))}.</p>"
    else:
        figures.append("<p>Sparse data (a gonioreflectometer file) cannot be rendered from "
                       "themselves: only the fit is.</p>")
    slices = [_img(_figure_png(plot.in_plane_slices(data, [(label, result.model)],
                                                    (0.0, 30.0, 60.0))),
                   "in-plane slices", "data and fit in the plane of incidence"),
              _img(_figure_png(plot.residuals(data, [(label, result.model)])),
                   "residuals", "ln(fit / data) per sample against the half-vector angle")]
    if table is not None:
        slices.append(_img(_figure_png(plot.rusinkiewicz_slice(table, [(label, result.model)])),
                           "Rusinkiewicz slice",
                           "the phi_d = 90 degree slice of data and fit, and their log ratio"))

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
    when = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    parts.append(f"<h2>Provenance</h2><p><code>{html.escape(command)}</code></p><p>brdf_fit "
                 f"{html.escape(__version__)}, Python {platform.python_version()}, "
                 f"{html.escape(platform.platform())}, {when}.</p>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(result.model_name)}: {html.escape(source)}</title>"
            f"<style>{_STYLE}</style></head><body>\n" + "\n".join(parts)
            + "\n</body></html>\n")
