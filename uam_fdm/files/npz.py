"""`.npz` files whose bytes depend on their arrays only: the same arrays give the same file, byte for byte.

NumPy's `savez` stamps each entry with the current time, so two identical recordings differ on disk;
here every entry carries the zip format's earliest date (1980-01-01), the entries are written in the order
given, and the file is written atomically (`uam_fdm.files.atomic`). `numpy.load(..., allow_pickle=False)`
reads it like any `.npz`.
"""
from __future__ import annotations

import io
import zipfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from uam_fdm.files.atomic import atomic_open

_EPOCH = (1980, 1, 1, 0, 0, 0)  # the zip format's earliest date: a fixed stamp instead of the clock


def write_npz(path: Path | str, arrays: Mapping[str, np.ndarray], compress: bool = True, *,
              root: Path | str | None = None) -> Path:
    """Write `arrays` (name -> array, no objects) to `path` reproducibly and atomically (`root`: the folder this
    tool owns that `path` lies in, as `uam_fdm.files.atomic.atomic_path`'s); returns the path.

    Raises:
        ValueError: an array of Python objects (it would need pickling).
    """
    path = Path(path)
    with atomic_open(path, "wb", root=root) as f, zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED if compress
                                                         else zipfile.ZIP_STORED) as z:
        for name, value in arrays.items():
            a = np.asarray(value)
            if a.dtype.hasobject:
                raise ValueError(f"{path}: array {name!r} holds Python objects")
            buf = io.BytesIO()
            np.lib.format.write_array(buf, a, allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_EPOCH)
            info.compress_type = z.compression
            info.external_attr = 0o644 << 16
            z.writestr(info, buf.getvalue())
    return path
