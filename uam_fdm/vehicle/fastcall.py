"""Call a compiled CasADi function for N vehicles through the library's `uam_batch_eval` driver.

Same compiled code as `casadi.external` loads, without CasADi's per-call conversion overhead:
inputs are NumPy arrays, one row per vehicle (or shared by all), outputs are preallocated arrays.
Only functions whose inputs and outputs are all dense are supported (checked at construction).
"""
from __future__ import annotations

import ctypes
from pathlib import Path

import casadi as ca
import numpy as np

_I64 = ctypes.c_longlong


class BatchCaller:
    """Evaluate one compiled function row-wise over a batch.

    Args:
        library: path of the shared library built by `uam_fdm.vehicle.codegen`.
        function: the CasADi Function (for its name and shapes); it must have been compiled into `library`.
    """

    def __init__(self, library: Path, function: ca.Function) -> None:
        self._lib = ctypes.CDLL(str(library))
        name = function.name()
        for i in range(function.n_in()):
            if not function.sparsity_in(i).is_dense():
                raise ValueError(f"{name}: input {i} is not dense")
        for i in range(function.n_out()):
            if not function.sparsity_out(i).is_dense():
                raise ValueError(f"{name}: output {i} is not dense")
        self.name = name
        self.in_sizes = [function.numel_in(i) for i in range(function.n_in())]
        self.out_shapes = [function.size_out(i) for i in range(function.n_out())]
        self._out_sizes = [r * c for r, c in self.out_shapes]
        self._eval = ctypes.cast(getattr(self._lib, name), ctypes.c_void_p)
        self._work = ctypes.cast(getattr(self._lib, f"{name}_work"), ctypes.c_void_p)
        # ctypes array types of the driver's pointer and stride arguments; the output strides never
        # change (one row per vehicle) and are only read by the driver, so one array serves all calls.
        self._in_ptrs = ctypes.c_void_p * len(self.in_sizes)
        self._in_strides = _I64 * len(self.in_sizes)
        self._out_ptrs = ctypes.c_void_p * len(self._out_sizes)
        self._out_stride = (_I64 * len(self._out_sizes))(*self._out_sizes)
        driver = self._lib.uam_batch_eval
        driver.argtypes = [ctypes.c_void_p, ctypes.c_void_p, _I64, _I64, ctypes.c_void_p, ctypes.c_void_p,
                           _I64, ctypes.c_void_p, ctypes.c_void_p]
        driver.restype = ctypes.c_int
        self._driver = driver

    def __call__(self, n: int, *inputs: np.ndarray | float) -> list[np.ndarray]:
        """Evaluate for `n` vehicles.

        Args:
            n: number of vehicles.
            inputs: per input, an array of shape (n, size) (one row per vehicle) or of `size`
                elements (shared by all vehicles); scalars are shared.

        Returns:
            One array per output of shape (n, rows*cols): each row is the vehicle's output in
            column-major order (for an (r, c) output, reshape the row to (c, r) to get columns as rows).
        """
        if len(inputs) != len(self.in_sizes):
            raise ValueError(f"{self.name}: expected {len(self.in_sizes)} inputs, got {len(inputs)}")
        arrays, strides = [], []
        for k, (value, size) in enumerate(zip(inputs, self.in_sizes)):
            a = np.ascontiguousarray(value, dtype=np.float64)
            if a.size == size:
                strides.append(0)
            elif a.shape == (n, size):
                strides.append(size)
            else:
                raise ValueError(f"{self.name}: input {k} has shape {a.shape}, expected ({n}, {size}) or ({size},)")
            arrays.append(a)
        outputs = [np.empty((n, size)) for size in self._out_sizes]
        in_ptr = self._in_ptrs(*map(_address, arrays))
        out_ptr = self._out_ptrs(*map(_address, outputs))
        failed = self._driver(self._eval, self._work, n, len(arrays), in_ptr, self._in_strides(*strides), len(outputs),
                              out_ptr, self._out_stride)
        if failed:
            raise RuntimeError(f"{self.name}: compiled evaluation reported an error")
        return outputs


def _address(a: np.ndarray) -> int:
    """The data address of a C-contiguous array.

    Through a ctypes view of its buffer (~0.5 µs): `ndarray.ctypes.data` and `__array_interface__`
    build an object per access (~2 µs each), which with nine addresses per call dominated a single
    vehicle's evaluation. Read-only or empty arrays (no writable buffer to view) take the slow way.
    """
    try:
        # NumPy's stubs give ndarray the buffer protocol only for Python >= 3.12
        return ctypes.addressof(ctypes.c_char.from_buffer(a))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return a.ctypes.data


def map_rows(f: ca.Function, maps: dict[tuple[str, int], ca.Function], n: int,
             *inputs: np.ndarray | float) -> list[np.ndarray]:
    """`BatchCaller`'s layout through CasADi's virtual machine (no compiler): `f` mapped over n vehicles.

    Args:
        f: the Function.
        maps: a cache of mapped Functions, keyed by (name, n), kept by the caller.
        n: number of vehicles.
        inputs: per input, (n, size) with one column-major row per vehicle, or one value shared by all.

    Returns:
        One array per output of shape (n, rows*cols), column-major per vehicle.
    """
    key = (f.name(), n)
    if key not in maps:
        maps[key] = f.map(n, "serial")
    args = []
    for k, a in enumerate(inputs):
        a = np.asarray(a, float)
        if a.ndim == 2:  # one column-major row per vehicle -> the vehicles' matrices side by side
            r, c = f.size_in(k)
            a = a.reshape(n * c, r).T
        args.append(a)
    outs = maps[key](*args)
    outs = outs if isinstance(outs, (list, tuple)) else [outs]
    result = []
    for k, o in enumerate(outs):
        r, c = f.size_out(k)
        result.append(np.asarray(o.full()).reshape(r, n, c).transpose(1, 2, 0).reshape(n, r * c))
    return result
