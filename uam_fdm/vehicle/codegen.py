"""Compile CasADi Functions to C at first use and cache the shared library on disk.

The cache key is a hash of the generated C source, the compiler command and the CasADi version,
so a changed model (or vehicle) never loads stale code. The library is written under a
temporary name and renamed into place, so parallel processes can race to build it safely.
Without a working C compiler the caller gets ``None`` and keeps CasADi's virtual machine.
"""
from __future__ import annotations

import hashlib
import logging
import os
import shlex
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

log = logging.getLogger(__name__)

# Appended to the generated source: evaluates one generated function for N vehicles in one C call.
# Serial on purpose: on a shared 2-core machine threads spin against the other process (measured
# 10x slower); parallelism belongs at process level. Input k of vehicle v starts at in[k] + v*in_stride[k]
# (stride 0 = shared by all vehicles); outputs likewise. Called through ctypes by `uam_fdm.vehicle.fastcall`,
# because CasADi's own Python call costs tens of microseconds for a function that computes in one.
BATCH_DRIVER_C = r"""
#include <stdlib.h>
typedef int (*uam_eval_t)(const casadi_real**, casadi_real**, casadi_int*, casadi_real*, int);
typedef int (*uam_work_t)(casadi_int*, casadi_int*, casadi_int*, casadi_int*);

CASADI_SYMBOL_EXPORT int uam_batch_eval(uam_eval_t f, uam_work_t work, casadi_int n, casadi_int n_in,
                                        const casadi_real** in, const casadi_int* in_stride, casadi_int n_out,
                                        casadi_real** out, const casadi_int* out_stride) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  int failed = 0;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real* w;
  casadi_int v, k;
  work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  arg = malloc((sz_arg + 1) * sizeof(casadi_real*));
  res = malloc((sz_res + 1) * sizeof(casadi_real*));
  iw = malloc((sz_iw + 1) * sizeof(casadi_int));
  w = malloc((sz_w + 1) * sizeof(casadi_real));
  for (v = 0; v < n; ++v) {
    for (k = 0; k < n_in; ++k) arg[k] = in[k] + v * in_stride[k];
    for (k = 0; k < n_out; ++k) res[k] = out[k] + v * out_stride[k];
    if (f(arg, res, iw, w, 0)) failed = 1;
  }
  free(arg); free(res); free(iw); free(w);
  return failed;
}
"""


def default_cache_dir() -> Path:
    """`$UAM_FDM_CACHE`, else `$XDG_CACHE_HOME/uam-compare/casadi`, else `~/.cache/uam-compare/casadi`."""
    if os.environ.get("UAM_FDM_CACHE"):
        return Path(os.environ["UAM_FDM_CACHE"])
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "uam-compare" / "casadi"


def compiler_command() -> list[str] | None:
    """The C compiler to use (`$CC`, else cc/gcc/clang on PATH), or None when there is none."""
    candidates = [os.environ["CC"]] if os.environ.get("CC") else ["cc", "gcc", "clang"]
    for cand in candidates:
        argv = shlex.split(cand)
        if argv and shutil.which(argv[0]):
            return argv
    return None


@dataclass(frozen=True)
class CompiledLibrary:
    """A compiled shared library: its path and the Functions loaded back through CasADi."""

    path: Path
    functions: dict[str, ca.Function]


def compile_source(source: bytes, name: str, cache_dir: Path | None = None,
                   opt_flags: tuple[str, ...] = ("-O3", "-march=native"),
                   link_args: tuple[str, ...] = ()) -> Path | None:
    """Compile C `source` into a shared library in the cache (or reuse the cached one).

    `link_args` (include paths, libraries) follow the source on the command line, where a linker
    that drops unused libraries still sees what the source needs.

    Returns:
        The library's path, or None when no compiler is available or compilation failed (logged).
    """
    cc = compiler_command()
    if cc is None:
        log.warning("no C compiler found ($CC, cc, gcc, clang): using CasADi's virtual machine (slower)")
        return None
    cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    flags = (*opt_flags, "-fPIC", "-shared")
    version = ca.__version__  # type: ignore[attr-defined]  # set in casadi/__init__.py, absent from its stubs
    key = hashlib.sha256(source + repr((cc, flags, link_args, version)).encode()).hexdigest()[:20]
    lib_path = cache_dir / f"{name}_{key}.so"
    if lib_path.exists():
        return lib_path
    cache_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="uam_codegen_") as tmp:
        source_path = Path(tmp) / f"{name}.c"
        source_path.write_bytes(source)
        tmp_lib = cache_dir / f".{lib_path.name}.{os.getpid()}.tmp"
        cmd = [*cc, *flags, str(source_path), *link_args, "-o", str(tmp_lib), "-lm"]
        log.info("compiling %s (%d kB of C)", name, len(source) // 1024)
        try:
            result = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
        except (OSError, subprocess.TimeoutExpired) as exc:
            log.warning("compiling %s failed (%s): using CasADi's virtual machine", name, exc)
            return None
        if result.returncode != 0:
            log.warning("compiling %s failed: %s\n%s: using CasADi's virtual machine",
                        name, " ".join(cmd), result.stderr[-2000:])
            tmp_lib.unlink(missing_ok=True)
            return None
        os.replace(tmp_lib, lib_path)
    log.info("compiled %s -> %s", name, lib_path)
    return lib_path


def compile_functions(functions: list[ca.Function], name: str,
                      cache_dir: Path | None = None) -> CompiledLibrary | None:
    """Generate C for `functions` (plus the batch driver), compile or reuse a cached build, load them back.

    Args:
        functions: CasADi Functions with distinct names.
        name: a readable prefix for the generated file.
        cache_dir: where shared libraries are kept (default `default_cache_dir()`).

    Returns:
        The library (path and ``{function name: external Function}``), or None if no compiler is
        available or the build failed (logged as a warning; the caller then uses the VM Functions).
    """
    gen = ca.CodeGenerator(f"{name}.c", {"with_header": False})
    for f in functions:
        gen.add(f)
    lib_path = compile_source(gen.dump().encode() + BATCH_DRIVER_C.encode(), name, cache_dir)
    if lib_path is None:
        return None
    return CompiledLibrary(lib_path, {f.name(): ca.external(f.name(), str(lib_path)) for f in functions})
