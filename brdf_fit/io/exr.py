"""OpenEXR images as NumPy arrays, through the official bindings (``pip install OpenEXR``, the
3.x ``OpenEXR.File`` API; an optional dependency, imported only when an ``.exr`` file is read or
written): :func:`read_exr` and :func:`write_exr`.

Channel names follow OpenEXR's "Interpreting OpenEXR Images" conventions (:func:`channel_names`):
one channel is ``Y`` (luminance), two ``R, G``, three ``R, G, B``, four ``R, G, B, A``; more keep
the names given. Files are single-part scan-line images with ``ZIP_COMPRESSION`` (lossless) and
``FLOAT`` (32-bit) pixels, or ``HALF`` on request. Row 0 of an array is the image's top row
(OpenEXR's ``INCREASING_Y`` line order, the data window's first line).
"""

from __future__ import annotations

import pathlib

import numpy as np

__all__ = ["read_exr", "write_exr", "channel_names", "EXTRA"]

#: how to install the optional OpenEXR bindings
EXTRA = "pip install OpenEXR (or pip install 'brdf_fit[tables]')"
_NAMES = {1: ("Y",), 2: ("R", "G"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}
# the order in which a file's channels become array channels: the conventional names first
_ORDER = ("R", "G", "B", "A", "Y")


def _openexr(action: str):
    try:
        import OpenEXR
    except ImportError:
        raise ImportError(f"{action} needs the OpenEXR package: {EXTRA}") from None
    return OpenEXR


def channel_names(n: int, names=None) -> tuple[str, ...]:
    """The EXR channel names of an image with ``n`` channels: the conventional ``Y`` /
    ``R, G`` / ``R, G, B`` / ``R, G, B, A`` for 1-4, else ``names`` (required then)."""
    if n in _NAMES:
        return _NAMES[n]
    if names is None or len(names) != n:
        raise ValueError(f"an EXR image of {n} channels needs {n} channel names")
    return tuple(str(c) for c in names)


def read_exr(path) -> tuple[np.ndarray, tuple[str, ...], dict]:
    """``(image, channels, header)`` of an OpenEXR file: ``image`` (H, W, C) float32 (half
    pixels exactly), ``channels`` its channel names in array order (``R, G, B, A`` and ``Y``
    first, in that order, then the others sorted), ``header`` the file's header attributes.
    Raises ValueError naming the file when it cannot be read (not an EXR, truncated, a
    multi-part or deep file)."""
    OpenEXR = _openexr(f"reading {path}")
    where = str(path)
    if not pathlib.Path(path).is_file():
        raise ValueError(f"{where}: no such file")
    try:
        with OpenEXR.File(where, separate_channels=True) as exr:
            header = dict(exr.header())
            chans = {n: np.asarray(c.pixels) for n, c in exr.channels().items()}
    except Exception as e:  # the bindings raise RuntimeError / ValueError / their own kinds
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ValueError(f"{where}: not a readable OpenEXR image ({first})") from None
    if not chans:
        raise ValueError(f"{where}: an OpenEXR image without channels")
    names = [n for n in _ORDER if n in chans] + sorted(n for n in chans if n not in _ORDER)
    shapes = {chans[n].shape for n in names}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"{where}: channels of different sizes {sorted(shapes)} (subsampled "
                         "channels are not supported)")
    image = np.stack([np.asarray(chans[n], np.float32) for n in names], axis=-1)
    return image, tuple(names), header


def write_exr(path, image, channels=None, attributes: dict | None = None,
              half: bool = False) -> pathlib.Path:
    """Write ``image`` ((H, W) or (H, W, C), any real dtype; stored as float32, or float16 with
    ``half``) to ``path`` as a single-part scan-line OpenEXR file, ZIP-compressed (lossless).
    ``channels``: names for C > 4 (:func:`channel_names`); ``attributes``: string header
    attributes to add (e.g. a JSON description). Writes ``path`` directly; callers wanting an
    atomic write pass a temporary path and rename it."""
    OpenEXR = _openexr(f"writing {path}")
    a = np.asarray(image)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{path}: an EXR image needs shape (H, W) or (H, W, C), got {a.shape}")
    names = channel_names(a.shape[2], channels)
    dtype = np.float16 if half else np.float32
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update({str(k): str(v) for k, v in (attributes or {}).items()})
    pixels = {n: np.ascontiguousarray(a[..., k], dtype=dtype) for k, n in enumerate(names)}
    with OpenEXR.File(header, pixels) as exr:
        exr.write(str(path))
    return pathlib.Path(path)
