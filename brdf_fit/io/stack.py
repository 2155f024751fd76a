"""Image stacks: a texture-scale capture as M images of one surface, each taken under one light
direction from one view direction, described by a JSON file (layer 2).

A *stack description* (``stack.json``; paths relative to its folder)::

    {
      "format": "brdf_fit.image_stack/1",
      "quantity": "brdf",                  # optional: brdf (default), brf, brdfcos
      "scale": 1.0,                        # optional: every value is multiplied by it first
      "channels": ["R", "G", "B"],         # optional: which image channels, in this order
      "images": [
        {"file": "img_000.exr", "wi": [0.0, 0.0, 1.0], "wo": [0.5, 0.0, 0.866]},
        {"file": "img_001.exr", "theta_i": 30, "phi_i": 0, "theta_o": 45, "phi_o": 180},
        ...
      ]
    }

Every texel of every image is one BRDF sample of that texel's material, for the image's light
direction ``wi`` and view direction ``wo`` in the surface's local frame (z the normal, the
tangent along the image's x axis): unit vectors (normalised when given otherwise; zero or below
the horizon refused), or angles in degrees (``theta_i, phi_i, theta_o, phi_o``, the convention
of the gonioreflectometer CSV, :mod:`brdf_fit.io.csv`). ``quantity`` is what the pixels hold,
converted to BRDF in 1/sr as the CSV reader does: ``brdf`` (as is), ``brf`` (reflectance factor,
divided by pi), ``brdfcos`` (BRDF x cos(theta_o), divided by the image's cos(theta_o)).
Images are OpenEXR (``.exr``, linear values; the optional OpenEXR bindings) or NumPy (``.npy``,
(H, W) or (H, W, C)); all of one size and channel count. Without ``channels`` an EXR's
``R, G, B`` are taken when present, else ``Y``, else its single channel. Non-finite pixels
(NaN, inf: not measured) are masked (weight 0) in their texel's fit, not refused.

:func:`read_stack` checks the description and every image's header (size, channels) before any
pixel is read, naming the file and the problem (:class:`~brdf_fit.data.DataError`).
:meth:`ImageStack.to_values` writes the pixels once, image by image (one image in memory at a
time), into a memory-mapped ``.npy`` file laid out image-major, (M, H x W, C), and returns the
(N, M, C) view :func:`~brdf_fit.fitting.stream.fit_stream` reads block by block (a block's
M strided runs of contiguous texels). :func:`write_maps` writes parameter maps as ``.npy``
(H, W[, C]) and, on request, OpenEXR.

    stack = read_stack("capture/stack.json")
    values = stack.to_values("fits/values.npy")          # (H*W, M, C), memory-mapped
    res = fit_stream(values, "ggx", "fits/", wi=stack.wi, wo=stack.wo)
    write_maps("fits/maps", stack.to_maps(res.result()), exr=True)
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import pathlib

import numpy as np

from brdf_fit.core.atomic import atomic_path
from brdf_fit.core.limits import check_bytes
from brdf_fit.data import DataError
from brdf_fit.io.csv import QUANTITIES

__all__ = ["ImageStack", "read_stack", "write_stack", "write_maps", "result_maps", "STACK_FORMAT",
           "IMAGE_EXTENSIONS"]

STACK_FORMAT = "brdf_fit.image_stack/1"
IMAGE_EXTENSIONS = (".exr", ".npy")
#: a direction's length may differ from 1 by this much and still be taken as given (beyond it
#: the vector is normalised); a length below NORM_MIN is refused as no direction at all
NORM_TOLERANCE = 1e-6
NORM_MIN = 1e-12
_KEYS = {"format", "quantity", "scale", "channels", "images", "description"}
_IMAGE_KEYS = {"file", "wi", "wo", "theta_i", "phi_i", "theta_o", "phi_o"}
_ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")


#: memory per pixel value while one image is read into the values file: the pixels as read
#: (up to float64), their float64 copy and its scaled copy (:meth:`ImageStack.to_values`)
STACK_BYTES_PER_VALUE = 24


def _err(where, msg) -> DataError:
    return DataError(f"{where}: {msg}")


def _npy_names(n: int) -> tuple[str, ...]:
    """The channel names of a ``.npy`` image of ``n`` channels: ``Y``; ``R, G``; ``R, G, B``;
    else ``0, 1, ...``."""
    return ("Y",) if n == 1 else ("R", "G", "B")[:n] if n <= 3 else tuple(map(str, range(n)))


def _image_header(path: pathlib.Path) -> tuple[tuple[int, int], tuple[str, ...]]:
    """``((H, W), channel names)`` of one image, reading only its header."""
    if path.suffix.lower() == ".npy":
        try:
            a = np.load(path, mmap_mode="r")
        except (OSError, ValueError) as e:
            raise _err(path, f"not a readable .npy image ({e})") from None
        if a.ndim not in (2, 3) or not np.issubdtype(a.dtype, np.number):
            raise _err(path, f"a .npy image is (H, W) or (H, W, C) numbers, got {a.shape} "
                       f"{a.dtype}")
        return a.shape[:2], _npy_names(1 if a.ndim == 2 else a.shape[2])
    from brdf_fit.io.exr import _openexr

    OpenEXR = _openexr(f"reading {path}")
    try:
        with OpenEXR.File(str(path), separate_channels=True, header_only=True) as exr:
            h = exr.header()
            (x0, y0), (x1, y1) = np.asarray(h["dataWindow"]).reshape(2, 2).tolist()
            names = tuple(getattr(c, "name", c) for c in h["channels"])
    except Exception as e:  # the bindings raise several kinds
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise _err(path, f"not a readable OpenEXR image ({first})") from None
    return (y1 - y0 + 1, x1 - x0 + 1), tuple(sorted(names))


def _read_image(path: pathlib.Path, channels) -> tuple[np.ndarray, tuple[str, ...]]:
    """``(pixels (H, W, C), names)``, the named ``channels`` (or all) of one image."""
    if path.suffix.lower() == ".npy":
        a = np.load(path)
        a = a[..., None] if a.ndim == 2 else a
        names = _npy_names(a.shape[2])
    else:
        from brdf_fit.io.exr import read_exr

        try:
            a, names, _ = read_exr(path)
        except ValueError as e:
            raise DataError(str(e)) from None
    if channels is None:
        return a, tuple(names)
    missing = [c for c in channels if c not in names]
    if missing:
        raise _err(path, f"no channel {missing[0]!r} (it has {', '.join(names)})")
    return a[..., [names.index(c) for c in channels]], tuple(channels)


def _refuse_negative(path, px: np.ndarray) -> None:
    """Refuse an image (H, W, C) with a negative pixel value, naming the file, how many and the
    first (x, y): a reflectance is >= 0, and a negative one made every fit of its texel fail
    with nothing saying why (issue 45). Non-finite pixels are not refused: they mark texels
    not measured in that image (masked out of the fit)."""
    neg = px < 0  # NaN compares False: not counted
    k = int(np.count_nonzero(neg))
    if k:
        y, x, c = (int(i) for i in np.argwhere(neg)[0])
        raise _err(path, f"{k:,} negative pixel value(s), the first at x={x}, y={y}, channel "
                   f"{c} ({float(px[y, x, c])!r}); reflectance values are >= 0 (non-finite "
                   "pixels are taken as not measured)")


def _direction(where, img: dict, which: str) -> np.ndarray:
    """The unit vector ``wi`` or ``wo`` of one image entry (vector or angles in degrees)."""
    t, p = f"theta_{which[1]}", f"phi_{which[1]}"
    if which in img and (t in img or p in img):
        raise _err(where, f"give {which} or {t}/{p}, not both")
    if which in img:
        try:
            v = np.asarray(img[which], float)
        except (TypeError, ValueError):
            v = np.zeros(0)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise _err(where, f"{which} must be three finite numbers, got {img[which]!r}")
    elif t in img and p in img:
        try:
            th, ph = np.radians(float(img[t])), np.radians(float(img[p]))
        except (TypeError, ValueError):
            raise _err(where, f"{t} and {p} must be numbers (degrees)") from None
        if not (np.isfinite(th) and np.isfinite(ph)):
            raise _err(where, f"{t} and {p} must be finite numbers (degrees), got "
                              f"{img[t]}, {img[p]}")
        if not (0.0 <= np.degrees(th) <= 90.0):
            raise _err(where, f"{t} = {img[t]} degrees is below the horizon (0..90)")
        v = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    else:
        raise _err(where, f"no {which} (a unit vector) or {t}, {p} (degrees)")
    n = float(np.linalg.norm(v))
    if n < NORM_MIN:
        raise _err(where, f"{which} = {v.tolist()} is not a direction (zero length)")
    if abs(n - 1.0) > NORM_TOLERANCE:
        v = v / n
    if v[2] < 0.0:
        raise _err(where, f"{which} = {v.tolist()} is below the horizon (z < 0)")
    return v


@dataclasses.dataclass(frozen=True)
class ImageStack:
    """A checked stack description (:func:`read_stack`): the image files, their directions
    ``wi``, ``wo`` (M, 3), the per-image factor to BRDF (``to_brdf``, (M,): the quantity's
    conversion times ``scale``), the image size ``shape`` (H, W) and the ``channels`` taken."""

    path: pathlib.Path
    files: tuple[pathlib.Path, ...]
    wi: np.ndarray
    wo: np.ndarray
    to_brdf: np.ndarray
    shape: tuple[int, int]
    channels: tuple[str, ...]
    quantity: str
    scale: float

    @property
    def n_images(self) -> int:
        return len(self.files)

    @property
    def n_texels(self) -> int:
        return self.shape[0] * self.shape[1]

    def fingerprint(self) -> dict:
        """What identifies the stack's data for a resumed run: the description's SHA-256, the
        image files' sizes and modification times, the shape and the channels."""
        files = [{"file": str(f), "bytes": f.stat().st_size, "mtime_ns": f.stat().st_mtime_ns}
                 for f in self.files]
        return {"stack": str(self.path), "sha256": hashlib.sha256(self.path.read_bytes()
                                                                   ).hexdigest(),
                "images": len(self.files), "shape": list(self.shape),
                "channels": list(self.channels),
                "files_sha256": hashlib.sha256(json.dumps(files).encode()).hexdigest()}

    def to_values(self, path, progress=None) -> np.ndarray:
        """Write every image's pixels, converted to BRDF (1/sr), into the memory-mapped
        ``.npy`` file ``path``, image-major (M, H x W, C) float32 (float64 when an image holds
        float64), one image read at a time, and return the (H x W, M, C) view :func:`~brdf_fit.
        fitting.stream.fit_stream` takes. A file written before for this stack (same shape,
        dtype, and a ``.done`` marker holding :meth:`fingerprint`) is reused without reading
        the images again. ``progress(done, total)`` is called after every image."""
        path = pathlib.Path(path)
        marker = path.with_name(path.name + ".done")
        mark = json.dumps(self.fingerprint(), sort_keys=True)
        M, N, C = self.n_images, self.n_texels, len(self.channels)
        if path.exists() and marker.exists() and marker.read_text() == mark:
            mm = np.load(path, mmap_mode="r")
            if mm.shape == (M, N, C):
                return np.moveaxis(mm, 0, 1)
        dtype = np.float32
        if any(f.suffix.lower() == ".npy" and np.load(f, mmap_mode="r").dtype == np.float64
               for f in self.files):
            dtype = np.float64
        if marker.exists():
            marker.unlink()
        with atomic_path(path) as tmp:
            mm = np.lib.format.open_memmap(tmp, mode="w+", dtype=dtype, shape=(M, N, C))
            for j, f in enumerate(self.files):
                px, _ = _read_image(f, self.channels)
                if px.shape[:2] != self.shape:
                    raise _err(f, f"size {px.shape[1]}x{px.shape[0]}, the stack's first image is "
                               f"{self.shape[1]}x{self.shape[0]}")
                _refuse_negative(f, px)
                mm[j] = px.reshape(N, C).astype(np.float64) * self.to_brdf[j]
                if progress is not None:
                    progress(j + 1, M)
            mm.flush()
            del mm
        marker.write_text(mark)
        return np.moveaxis(np.load(path, mmap_mode="r"), 0, 1)

    def to_maps(self, result) -> dict[str, np.ndarray]:
        """The per-texel arrays of a :class:`~brdf_fit.fitting.batch.BatchFitResult` of this
        stack's H x W problems, as images (H, W[, ...]): ``params_NAME``, ``stderr_NAME``,
        ``undetermined_NAME``, ``converged``, ``residual_rms``."""
        H, W = self.shape
        out = {}
        for name, a in result_maps(result).items():
            if a.shape[0] != H * W:
                raise ValueError(f"{name}: {a.shape[0]} problems, the stack has {H * W} texels")
            out[name] = a.reshape(H, W, *a.shape[1:])
        return out


def result_maps(result) -> dict[str, np.ndarray]:
    """The per-problem arrays of a :class:`~brdf_fit.fitting.batch.BatchFitResult` (N, ...) by
    map name: ``params_NAME``, ``stderr_NAME``, ``undetermined_NAME``, ``converged``,
    ``residual_rms`` (what :func:`write_maps` writes; :meth:`ImageStack.to_maps` shapes them
    as images)."""
    arrays = {f"params_{k}": v for k, v in result.params.items()}
    arrays.update({f"stderr_{k}": v for k, v in result.stderr.items()})
    arrays.update({f"undetermined_{k}": v for k, v in result.undetermined.items()})
    arrays.update({"converged": result.converged, "residual_rms": result.residual_rms})
    return {name: np.asarray(a) for name, a in arrays.items()}


def read_stack(path) -> ImageStack:
    """Read and check a stack description (the module docstring): every key, every image's
    directions, and every image's size and channels from its header, before any pixel is read.
    Raises :class:`~brdf_fit.data.DataError` naming the file (and image) and the problem."""
    path = pathlib.Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise _err(path, "no such file") from None
    except (OSError, ValueError) as e:
        raise _err(path, f"not a readable JSON stack description ({e})") from None
    if not isinstance(d, dict):
        raise _err(path, "a stack description is a JSON object")
    if d.get("format", STACK_FORMAT) != STACK_FORMAT:
        raise _err(path, f"format {d['format']!r}; this version reads {STACK_FORMAT!r}")
    unknown = sorted(set(d) - _KEYS)
    if unknown:
        raise _err(path, f"unknown key {unknown[0]!r} (known: {', '.join(sorted(_KEYS))})")
    quantity = str(d.get("quantity", "brdf")).lower()
    if quantity not in QUANTITIES:
        raise _err(path, f"quantity {d['quantity']!r}: expected one of {', '.join(QUANTITIES)}")
    try:
        scale = float(d.get("scale", 1.0))
    except (TypeError, ValueError):
        scale = float("nan")
    if not (np.isfinite(scale) and scale > 0):
        raise _err(path, f"scale must be a positive number, got {d.get('scale')!r}")
    images = d.get("images")
    if not isinstance(images, list) or not images:
        raise _err(path, "no images (a list of {\"file\", \"wi\", \"wo\"} objects)")
    files, wi, wo = [], [], []
    for j, img in enumerate(images):
        where = f"{path}, image {j}"
        if not isinstance(img, dict) or "file" not in img:
            raise _err(where, "each image is an object with \"file\" and its directions")
        bad = sorted(set(img) - _IMAGE_KEYS)
        if bad:
            raise _err(where, f"unknown key {bad[0]!r} (known: {', '.join(sorted(_IMAGE_KEYS))})")
        f = (path.parent / str(img["file"])).resolve()
        if f.suffix.lower() not in IMAGE_EXTENSIONS:
            raise _err(where, f"{img['file']}: images are {' or '.join(IMAGE_EXTENSIONS)} "
                       "(linear values; 8-bit images are not measurements)")
        if f.is_dir():
            raise _err(where, f"{img['file']}: a folder, not an image file")
        if not f.is_file():
            raise _err(where, f"{img['file']}: no such file")
        files.append(f)
        wi.append(_direction(where, img, "wi"))
        wo.append(_direction(where, img, "wo"))
    wi, wo = np.array(wi), np.array(wo)
    if quantity == "brdfcos" and np.any(wo[:, 2] <= 0.0):
        j = int(np.argmax(wo[:, 2] <= 0.0))
        raise _err(f"{path}, image {j}", "quantity brdfcos with a view at the horizon "
                   "(cos(theta_o) = 0): the BRDF cannot be recovered")
    factor = {"brdf": np.ones(len(files)), "brf": np.full(len(files), 1.0 / np.pi),
              "brdfcos": 1.0 / np.maximum(wo[:, 2], NORM_MIN)}[quantity] * scale
    shape, names = _image_header(files[0])
    chans = d.get("channels")
    if chans is not None:
        if not (isinstance(chans, list) and chans and all(isinstance(c, str) for c in chans)):
            raise _err(path, f"channels must be a list of channel names, got {chans!r}")
        channels = tuple(chans)
    elif {"R", "G", "B"} <= set(names):
        channels = ("R", "G", "B")
    elif "Y" in names:
        channels = ("Y",)
    elif len(names) == 1:
        channels = tuple(names)
    else:
        raise _err(files[0], f"channels {', '.join(names)}: say which to fit (\"channels\")")
    for f in files:
        s, n = _image_header(f)
        if s != shape:
            raise _err(f, f"size {s[1]}x{s[0]}; the stack's first image ({files[0].name}) is "
                       f"{shape[1]}x{shape[0]}")
        missing = [c for c in channels if c not in n]
        if missing:
            raise _err(f, f"no channel {missing[0]!r} (it has {', '.join(n)})")
        # an image is read whole, one at a time: its size (from the header, before any pixel
        # is read) against the memory limit, so that a header claiming 10^5 x 10^5 is refused
        check_bytes(float(s[0]) * s[1] * len(n) * STACK_BYTES_PER_VALUE,
                    f"{f}: an image of {s[1]}x{s[0]} x {len(n)} channel(s), read whole")
    return ImageStack(path=path.resolve(), files=tuple(files), wi=wi, wo=wo, to_brdf=factor,
                      shape=tuple(int(x) for x in shape), channels=channels, quantity=quantity,
                      scale=scale)


def write_stack(folder, images, wi, wo, *, fmt: str = "exr", quantity: str = "brdf",
                name: str = "stack.json", description: str | None = None) -> pathlib.Path:
    """Write an image stack: ``images`` (M, H, W[, C]) values (in ``quantity``), one file per
    image (``img_000.exr`` ... or ``.npy``) and the description ``name`` with the directions
    ``wi``, ``wo`` (M, 3). Returns the description's path (what :func:`read_stack` reads)."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    images = np.asarray(images)
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    if images.ndim not in (3, 4) or wi.shape != (images.shape[0], 3) or wo.shape != wi.shape:
        raise ValueError(f"images (M, H, W[, C]) with wi, wo (M, 3): got {images.shape}, "
                         f"{wi.shape}, {wo.shape}")
    if fmt not in ("exr", "npy"):
        raise ValueError(f"fmt must be 'exr' or 'npy', got {fmt!r}")
    entries = []
    width = max(3, len(str(images.shape[0] - 1)))
    for j in range(images.shape[0]):
        f = f"img_{j:0{width}d}.{fmt}"
        if fmt == "npy":
            np.save(folder / f, images[j])
        else:
            from brdf_fit.io.exr import write_exr

            write_exr(folder / f, images[j])
        entries.append({"file": f, "wi": wi[j].tolist(), "wo": wo[j].tolist()})
    d = {"format": STACK_FORMAT, "quantity": quantity}
    if description:
        d["description"] = description
    d["images"] = entries
    out = folder / name
    out.write_text(json.dumps(d, indent=1) + "\n")
    return out


def write_maps(folder, maps: dict[str, np.ndarray], *, exr: bool = False,
               attributes: dict | None = None) -> list[pathlib.Path]:
    """Write each map (an image (H, W[, C]), :meth:`ImageStack.to_maps`) as ``NAME.npy`` and,
    with ``exr``, ``NAME.exr`` (float32; booleans as 0/1; 1, 3 or 4 channels by OpenEXR's
    names, others as channels ``0, 1, ...``), each written to a temporary file and renamed.
    ``attributes``: string header attributes of every EXR (e.g. the model). Returns the
    paths written."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, a in maps.items():
        a = np.asarray(a)
        with atomic_path(folder / f"{name}.npy") as tmp, open(tmp, "wb") as fh:
            np.save(fh, a)
        written.append(folder / f"{name}.npy")
        if exr:
            from brdf_fit.io.exr import write_exr

            img = a.astype(np.float32).reshape(*a.shape[:2], -1)  # booleans as 0 / 1
            with atomic_path(folder / f"{name}.exr") as tmp:
                write_exr(tmp, img, [str(k) for k in range(img.shape[2])], attributes)
            written.append(folder / f"{name}.exr")
    return written
