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

The weights are the other cost: CasADi writes every weight matrix twice (``W`` for the forward
pass, ``Wᵀ`` for the gradient) as doubles, ~3.7 MB for a 3×256 distance MLP and a 3×128 SIREN,
more than a core's L2 cache, and each evaluation streams all of it. :func:`compact_weights`
stores each large matrix once, as ``float`` when every entry is exactly a float32 value (the
networks train in float32, so their weights are), and multiplies through it with two kernels
(one reads it transposed); the arithmetic stays double, so the results are those of the double
code up to the summation order. A constant whose uses do not match the expected pattern is left
as it is.

With ``single=True`` (the planner's default) the two kernels also multiply and sum in ``float``:
``V`` and ``∇V`` of the shipped ``ur5_ur5`` model move by at most 3e-8 over random states (the
tests bound it at 1e-6), far below the planner's margins, and its value and gradient at four
states take ~35 % less time here.

Two smaller costs: the ~2000 ``sin``/``cos``/``exp`` of one evaluation (the SIREN's activations and
their derivatives, the distance network's soft-min and layers) run four (AVX2) or eight (AVX-512)
at a time through glibc's vector math library (libmvec, x86-64; elsewhere, or when it does not
link, the scalar calls), and the ~60 4×4 products of the forward kinematics get a fixed-size
path in the product kernel.
Measured here on the shipped ``ur5_ur5`` value-and-gradient function: ~20–25 % faster together.
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
from nehmo_core.planning.numerics.compact import compact_weights
from nehmo_core.robots.loader import cache_dir

__all__ = ["BACKENDS", "CompiledFunction", "compact_weights", "compile_function", "compile_library"]

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
_CODEGEN_VERSION = "6"

_DENSE_KERNEL_HEAD = "void casadi_mtimes_dense(const casadi_real* x, casadi_int nrow_x"
_DENSE_KERNEL = (
    _DENSE_KERNEL_HEAD
    + """, casadi_int ncol_x,
    const casadi_real* y, casadi_int ncol_y, casadi_real* z, casadi_int tr) {
  casadi_int i, j, k;
  casadi_real acc;
  if (!tr && nrow_x == 4 && ncol_x == 4 && ncol_y == 4) { /* homogeneous transforms: unrolled */
    for (i=0; i<4; ++i) {
      for (j=0; j<4; ++j) {
        acc = 0;
        for (k=0; k<4; ++k) acc += x[j + k*4] * y[k + i*4];
        z[j + i*4] += acc;
      }
    }
  } else if (tr) {
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


def find_compiler() -> str | None:
    return os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")


def cpu_signature() -> str:
    """The CPU's model and feature flags (``-march=native`` code is tied to them)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.machine()
    keep = [ln for ln in lines if ln.startswith(("model name", "flags"))][:2]
    return platform.machine() + "|" + "|".join(keep)


_MATH_INCLUDE = "#include <math.h>\n"
_VECTOR_MATH = """#if defined(__x86_64__) && defined(__GLIBC__)
/* libmvec's vector variants, so that loops over these vectorize */
__attribute__((__simd__("notinbranch"))) extern double sin(double);
__attribute__((__simd__("notinbranch"))) extern double cos(double);
__attribute__((__simd__("notinbranch"))) extern double exp(double);
#endif
"""
VECTOR_MATH_FLAGS = ("-Wl,-z,defs", "-lmvec")
"""Link flags of the vector-math build: every symbol resolved (a missing libmvec fails the
build, which then falls back to the scalar calls) and glibc's vector math library."""


def _vector_math(source: str) -> str | None:
    """``source`` with libmvec's vector variants of ``sin``/``cos``/``exp`` declared, or
    ``None`` on a platform without them."""
    if platform.machine() not in ("x86_64", "AMD64") or _MATH_INCLUDE not in source:
        return None
    return source.replace(_MATH_INCLUDE, _MATH_INCLUDE + _VECTOR_MATH, 1)


def _patch_kernel(source: str) -> str:
    """Swap CasADi's dense product kernel for :data:`_DENSE_KERNEL` (unchanged if absent)."""
    start = source.find(_DENSE_KERNEL_HEAD)
    if start < 0:
        return source
    end = source.index("\n}\n", start) + 3
    return source[:start] + _DENSE_KERNEL + source[end:]


def _key(fn: ca.Function, compiler: str, compact: bool = True, single: bool = False) -> str:
    h = hashlib.sha256()
    parts = (
        fn.serialize(),
        ca.CasadiMeta.version(),
        compiler,
        " ".join(CFLAGS),
        _CODEGEN_VERSION + ("" if compact else "-plain") + ("-single" if single else ""),
        cpu_signature(),
    )
    for part in parts:
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:20]


def _build(
    fn: ca.Function, compiler: str, target: Path, compact: bool = True, single: bool = False
) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        source = f"{fn.name()}.c"
        cg = ca.CodeGenerator(source, {"with_header": False, "verbose": False})
        cg.add(fn)
        cg.generate(tmp + os.sep)
        path = Path(tmp) / source
        text = _patch_kernel(path.read_text())
        text = compact_weights(text, single)[0] if compact else text
        vector = _vector_math(text)
        if vector is not None:
            path.write_text(vector)
            try:
                compile_library(path, target, compiler, link=VECTOR_MATH_FLAGS)
                return
            except subprocess.CalledProcessError:
                pass  # no libmvec: the scalar calls
        path.write_text(text)
        compile_library(path, target, compiler)


def compile_library(
    source: Path,
    target: Path,
    compiler: str,
    flags: tuple[str, ...] = CFLAGS,
    link: tuple[str, ...] = (),
) -> None:
    """Compile C ``source`` into the shared library ``target`` (written atomically: concurrent
    builders never see a partial file); ``link``: extra linker flags."""
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        library = Path(tmp) / "lib.so"
        cmd = [compiler, *flags, str(source), "-o", str(library), *link, "-lm"]
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        os.replace(library, target)


def compile_function(
    fn: ca.Function, backend: str = "auto", compact: bool = True, single: bool = False
) -> CompiledFunction:
    """Evaluate ``fn`` through cached generated C (``backend`` in :data:`BACKENDS`).

    ``compact=False`` keeps CasADi's weight layout (for comparisons: same results, slower);
    ``single=True`` computes the compacted weights' products in float (see above; the VM
    ignores it).
    """
    if backend not in BACKENDS:
        raise UnknownNameError("backend", backend, BACKENDS)
    if backend == "vm":
        return CompiledFunction(fn, "vm")
    compiler = find_compiler()
    try:
        if compiler is None:
            raise FileNotFoundError("no C compiler (gcc or cc) on PATH")
        key = _key(fn, compiler, compact, single)
        target = cache_dir() / "casadi" / f"{fn.name()}_{key}.so"
        if not target.exists():
            _build(fn, compiler, target, compact, single)
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
