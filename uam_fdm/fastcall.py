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
        library: path of the shared library built by `uam_fdm.codegen`.
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
        self._eval = ctypes.cast(getattr(self._lib, name), ctypes.c_void_p)
        self._work = ctypes.cast(getattr(self._lib, f"{name}_work"), ctypes.c_void_p)
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
        outputs = [np.empty((n, r * c)) for r, c in self.out_shapes]
        in_ptr = np.array([a.ctypes.data for a in arrays], dtype=np.uintp)
        out_ptr = np.array([o.ctypes.data for o in outputs], dtype=np.uintp)
        in_stride = np.array(strides, dtype=np.int64)
        out_stride = np.array([o.shape[1] for o in outputs], dtype=np.int64)
        failed = self._driver(self._eval, self._work, n, len(arrays), in_ptr.ctypes.data, in_stride.ctypes.data,
                              len(outputs), out_ptr.ctypes.data, out_stride.ctypes.data)
        if failed:
            raise RuntimeError(f"{self.name}: compiled evaluation reported an error")
        return outputs
