"""`.npz` files whose bytes depend on their arrays only: the same arrays give the same file, byte for byte.

NumPy's `savez` stamps each entry with the current time, so two identical recordings differ on disk;
here every entry carries the zip format's earliest date (1980-01-01), the entries are written in the order
given, and the file is written atomically (`uam_fdm.files.atomic`). `numpy.load(..., allow_pickle=False)`
reads it like any `.npz`. Reading: `npz_read_errors` turns whatever a damaged file raises into one error naming
it; `check_declared_size` refuses, unread, a file whose arrays would inflate past a bound.
"""
from __future__ import annotations

import io
import math
import zipfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
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


@contextmanager
def npz_read_errors(path: Path, kind: str) -> Iterator[None]:
    """Reading `path` inside: every error becomes one ValueError naming the file ("not a `kind` .npz file" or
    "unreadable"); a ValueError that already names it passes as it is."""
    try:
        yield
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a {kind} .npz file ({exc})") from None
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"{path}: unreadable ({exc})") from None


def check_declared_size(path: Path, max_bytes: int) -> None:
    """Refuse, unread, an `.npz` whose arrays would take more than `max_bytes` in memory: the uncompressed sizes
    its zip directory declares (zipfile never inflates a member past its declared size) and, as each member's
    header is read, the size its shape and type declare (which must fit in the member).

    Raises:
        ValueError: over `max_bytes`, a header that claims more than its member holds, an array of objects, or
            not a readable `.npz`, naming the file (and the array).
    """
    with npz_read_errors(path, "plain-array"), zipfile.ZipFile(path) as z:
        members = z.infolist()
        declared = sum(i.file_size for i in members)
        if declared > max_bytes:
            raise ValueError(f"{path}: its arrays would take {declared / 2**20:,.0f} MiB in memory (the sizes "
                             f"its zip directory declares); at most {max_bytes / 2**20:,.0f} MiB: refused unread")
        for info in members:
            with z.open(info) as fp:
                version = np.lib.format.read_magic(fp)
                header = _HEADER_READERS.get(version)
                if header is None:
                    raise ValueError(f"{path}: array {info.filename!r} is in .npy format {version}, not one "
                                     "this tool writes")
                shape, _fortran, dtype = header(fp)
            if dtype.hasobject:
                raise ValueError(f"{path}: array {info.filename!r} holds Python objects")
            if math.prod(shape) * dtype.itemsize > info.file_size:
                raise ValueError(f"{path}: array {info.filename!r} claims {shape} of {dtype}, more than the "
                                 f"{info.file_size:,} bytes it holds")


_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
