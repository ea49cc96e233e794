"""Generated C for CasADi functions, compiled with the system compiler once and cached on disk.

``compile_function(fn)`` writes ``fn``'s C code, compiles it into a shared library under
``$NEHMO_CACHE/casadi/`` and loads it with ``casadi.external``. The cache key hashes the
serialized function (graph and every weight), the CasADi version, the compiler and its flags, so
a new model, compiler or CPU never reuses a stale library. Without a working compiler the
function runs on CasADi's virtual machine instead (same numbers, slower); the returned
:class:`CompiledFunction` says which backend is in use.

CasADi's dense product kernel accumulates into memory that may alias its inputs, so the compiler
can neither keep the sum in a register nor vectorize it. The generated source gets a drop-in
kernel with a local accumulator (same products, summed in a different order), compiled with
reassociation allowed (``-fassociative-math``, no ``-ffast-math``: infinities and NaNs keep
their meaning). Measured here on the value-and-gradient function of a 3×128 SIREN plus the
learned distance: ~3× faster than the unpatched code.
"""

from __future__ import annotations

import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

from nehmo_core.errors import UnknownNameError
from nehmo_core.robots.loader import cache_dir

__all__ = ["BACKENDS", "CompiledFunction", "compile_function"]

BACKENDS = ("auto", "compiled", "vm")
"""``compiled``: generated C (raise if that fails); ``vm``: CasADi's virtual machine;
``auto``: compiled when a compiler works, else the VM with a warning."""

CFLAGS = (
    "-O3",
    "-march=native",
    "-fno-math-errno",
    "-fassociative-math",
    "-fno-signed-zeros",
    "-fno-trapping-math",
    "-fPIC",
    "-shared",
)
_CODEGEN_VERSION = "2"

_DENSE_KERNEL_HEAD = "void casadi_mtimes_dense(const casadi_real* x, casadi_int nrow_x"
_DENSE_KERNEL = (
    _DENSE_KERNEL_HEAD
    + """, casadi_int ncol_x,
    const casadi_real* y, casadi_int ncol_y, casadi_real* z, casadi_int tr) {
  casadi_int i, j, k;
  casadi_real acc;
  if (tr) {
    for (i=0; i<ncol_y; ++i) {
      for (j=0; j<ncol_x; ++j) {
        acc = 0;
        for (k=0; k<nrow_x; ++k) acc += x[k + j*nrow_x] * y[k + i*nrow_x];
        z[j + i*ncol_x] += acc;
      }
    }
  } else if (nrow_x == 1) {
    for (i=0; i<ncol_y; ++i) {
      acc = 0;
      for (k=0; k<ncol_x; ++k) acc += x[k] * y[k + i*ncol_x];
      z[i] += acc;
    }
  } else {
    for (i=0; i<ncol_y; ++i) {
      for (j=0; j<nrow_x; ++j) {
        acc = 0;
        for (k=0; k<ncol_x; ++k) acc += x[j + k*nrow_x] * y[k + i*ncol_x];
        z[j + i*nrow_x] += acc;
      }
    }
  }
}
"""
)


@dataclass(frozen=True)
class CompiledFunction:
    """A CasADi function and the backend that evaluates it (``compiled`` or ``vm``)."""

    function: ca.Function
    backend: str
    library: Path | None = None


def _compiler() -> str | None:
    return os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")


def _cpu() -> str:
    """The CPU's model and feature flags (``-march=native`` code is tied to them)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.machine()
    keep = [ln for ln in lines if ln.startswith(("model name", "flags"))][:2]
    return platform.machine() + "|" + "|".join(keep)


def _patch_kernel(source: str) -> str:
    """Swap CasADi's dense product kernel for :data:`_DENSE_KERNEL` (unchanged if absent)."""
    start = source.find(_DENSE_KERNEL_HEAD)
    if start < 0:
        return source
    end = source.index("\n}\n", start) + 3
    return source[:start] + _DENSE_KERNEL + source[end:]


def _key(fn: ca.Function, compiler: str) -> str:
    h = hashlib.sha256()
    parts = (
        fn.serialize(),
        ca.CasadiMeta.version(),
        compiler,
        " ".join(CFLAGS),
        _CODEGEN_VERSION,
        _cpu(),
    )
    for part in parts:
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:20]


def _build(fn: ca.Function, compiler: str, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        source = f"{fn.name()}.c"
        cg = ca.CodeGenerator(source, {"with_header": False, "verbose": False})
        cg.add(fn)
        cg.generate(tmp + os.sep)
        path = Path(tmp) / source
        path.write_text(_patch_kernel(path.read_text()))
        library = Path(tmp) / "lib.so"
        cmd = [compiler, *CFLAGS, str(Path(tmp) / source), "-o", str(library), "-lm"]
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        os.replace(library, target)  # atomic: concurrent builders never see a partial file


def compile_function(fn: ca.Function, backend: str = "auto") -> CompiledFunction:
    """Evaluate ``fn`` through cached generated C (``backend`` in :data:`BACKENDS`)."""
    if backend not in BACKENDS:
        raise UnknownNameError("backend", backend, BACKENDS)
    if backend == "vm":
        return CompiledFunction(fn, "vm")
    compiler = _compiler()
    try:
        if compiler is None:
            raise FileNotFoundError("no C compiler (gcc or cc) on PATH")
        target = cache_dir() / "casadi" / f"{fn.name()}_{_key(fn, compiler)}.so"
        if not target.exists():
            _build(fn, compiler, target)
        return CompiledFunction(ca.external(fn.name(), str(target)), "compiled", target)
    except (OSError, subprocess.CalledProcessError, RuntimeError) as exc:
        if backend == "compiled":
            raise
        detail = getattr(exc, "stderr", "") or str(exc)
        warnings.warn(
            f"compiling {fn.name()} failed ({detail.strip()[:200]}); using CasADi's VM",
            RuntimeWarning,
            stacklevel=2,
        )
        return CompiledFunction(fn, "vm")
