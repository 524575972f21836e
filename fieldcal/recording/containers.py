"""What a recording file holds around its text: compressed text (gzip, xz, bzip2), read through
by the standard library, or a MATLAB MAT-file, whose variable becomes the text the map's
columns index. Told apart by their first bytes, not their names (imu_tk ships text as ``.mat``).

MAT-files v4 to v7.2 are read by ``scipy.io.loadmat``. v7.3 files are HDF5 underneath; reading
them would take h5py (and HDF5, some 10 MB) for a format MATLAB writes only when asked
(``save -v7.3``) or for variables over 2 GB, so they are named and refused, with the way out.
"""
from __future__ import annotations

import importlib
import io

import numpy as np

# A compressed file may unpack to this much text at most: a recording larger than this is not
# one that fits in memory to calibrate, and a small file that unpacks without end is no recording.
MAX_UNPACKED_BYTES = 4 << 30
# (first bytes, name, stdlib module and its opener, which takes a file object): the module imported only when one is seen.
_COMPRESSED = ((b"\x1f\x8b", "gzip", "gzip", "open"), (b"\xfd7zXZ\x00", "xz", "lzma", "open"),
               (b"BZh", "bzip2", "bz2", "open"))
_MAT_V5 = b"MATLAB 5.0 MAT-file"
_MAT_V73 = b"MATLAB 7.3 MAT-file"


class ContainerError(ValueError):
    """A file's container cannot be read; the message names the file and what would help."""


def is_compressed(data: bytes) -> bool:
    """Whether the bytes begin as a compressed stream this module unpacks."""
    return any(data.startswith(magic) for magic, *_ in _COMPRESSED)


def text_of(data: bytes, path: str, spec) -> bytes:
    """The text to parse from a file's bytes: as they are, unpacked, or a MAT-file's variable
    written as text in the delimiter of ``spec`` (an import map's FileSpec)."""
    for magic, name, module, opener in _COMPRESSED:
        if data.startswith(magic):
            data = _unpacked(data, getattr(importlib.import_module(module), opener), name, path)
            break
    if data.startswith(_MAT_V73):
        raise ContainerError(f"{path}: a MATLAB v7.3 MAT-file (HDF5), which fieldcal does not read: save it "
                             "again with save(..., '-v7') in MATLAB, or write the samples as text")
    if data.startswith(_MAT_V5):
        return _mat_text(data, path, spec)
    return data


def _unpacked(data: bytes, opener, name: str, path: str) -> bytes:
    errors = (OSError, EOFError, ValueError) + ((importlib.import_module("lzma").LZMAError,) if name == "xz" else ())
    try:
        with opener(io.BytesIO(data)) as stream:
            text = stream.read(MAX_UNPACKED_BYTES + 1)
    except errors as exc:

        raise ContainerError(f"{path}: {name}-compressed, but it cannot be unpacked ({exc})") from None
    if len(text) > MAX_UNPACKED_BYTES:
        raise ContainerError(f"{path}: {name}-compressed, and unpacks to more than "
                             f"{MAX_UNPACKED_BYTES >> 30} GiB: not a recording fieldcal can hold")
    return text


def _mat_text(data: bytes, path: str, spec) -> bytes:
    """The variable the map names (``variable``), or the file's only numeric matrix, as text:
    one sample per row, its columns numbered from 0 as a text file's are."""
    from scipy.io import loadmat  # only for a MAT-file

    where = f"the map's {spec.where or 'entry'}"
    if spec.channel_map is None:
        raise ContainerError(f"{path}: a MAT-file's columns have no names: give column numbers in {where}")
    try:
        variables = loadmat(io.BytesIO(data))
    except (ValueError, TypeError, OSError, NotImplementedError) as exc:
        raise ContainerError(f"{path}: a MATLAB MAT-file that cannot be read ({exc})") from None
    matrices = {k: v for k, v in variables.items() if not k.startswith("__") and isinstance(v, np.ndarray)
                and v.ndim == 2 and v.dtype.kind in "iuf" and v.size > 1}
    listed = ", ".join(f"{k} ({v.shape[0]}×{v.shape[1]})" for k, v in matrices.items()) or "none"
    name = getattr(spec, "variable", None)
    if name is None:
        if len(matrices) != 1:
            raise ContainerError(f"{path}: a MATLAB MAT-file with {len(matrices)} numeric matrices ({listed}): "
                                 f"name the one to read (variable: NAME in {where})")
        name = next(iter(matrices))
    if name not in matrices:
        raise ContainerError(f"{path}: the MAT-file has no numeric matrix {name!r} (its matrices: {listed})")
    values = matrices[name]
    if values.shape[0] < values.shape[1]:
        raise ContainerError(f"{path}: {name} is {values.shape[0]}×{values.shape[1]}: the samples must be its "
                             f"rows (save {name}.' in MATLAB)")
    delimiter = spec.channel_map.delimiter or " "
    out = io.BytesIO()
    fmt = "%d" if values.dtype.kind in "iu" else "%.17g"  # every double exactly, as strtod reads it back
    np.savetxt(out, values, fmt=fmt, delimiter=delimiter)
    return out.getvalue()
