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
import re
import shutil
import subprocess
import tempfile
import warnings
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from nehmo_core.errors import UnknownNameError
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


COMPACT_MIN_SIZE = 1024
"""Constants with fewer entries are left as doubles (a few KB: not worth a kernel call)."""

_CONST = re.compile(r"static const casadi_real (casadi_c\d+)\[(\d+)\] = \s*\{([^}]*)\};\n")
_ROWT_KERNEL = """
/* z (1 x m) += x (1 x n) * A^T, A (m x n) column-major in float; REAL: the arithmetic */
static void nehmo_rowt_f32(const casadi_real* x, casadi_int n, const float* a, casadi_int m,
    casadi_real* z) {
  REAL acc[NEHMO_ROWT_MAX];
  casadi_int i, k;
  for (i = 0; i < m; ++i) acc[i] = 0;
  for (k = 0; k + 4 <= n; k += 4) { /* four columns per pass over acc */
    const float *c0 = a + k*m, *c1 = c0 + m, *c2 = c1 + m, *c3 = c2 + m;
    REAL x0 = (REAL)x[k], x1 = (REAL)x[k+1], x2 = (REAL)x[k+2], x3 = (REAL)x[k+3];
    for (i = 0; i < m; ++i) acc[i] += x0*c0[i] + x1*c1[i] + x2*c2[i] + x3*c3[i];
  }
  for (; k < n; ++k) {
    REAL xk = (REAL)x[k];
    for (i = 0; i < m; ++i) acc[i] += xk*a[k*m + i];
  }
  for (i = 0; i < m; ++i) z[i] += acc[i];
}
"""
_ROW_KERNELS = """
/* z (1 x m) += x (1 x n) * Y, Y (n x m) column-major in float: 8 columns at a time */
static void nehmo_row_f32(const casadi_real* x, casadi_int n, const float* y, casadi_int m,
    casadi_real* z) {
  casadi_int i, k;
  for (i = 0; i + 8 <= m; i += 8) {
    const float* c = y + i*n;
    casadi_real a0 = 0, a1 = 0, a2 = 0, a3 = 0, a4 = 0, a5 = 0, a6 = 0, a7 = 0;
    for (k = 0; k < n; ++k) {
      casadi_real xk = x[k];
      a0 += xk*c[k]; a1 += xk*c[k + n]; a2 += xk*c[k + 2*n]; a3 += xk*c[k + 3*n];
      a4 += xk*c[k + 4*n]; a5 += xk*c[k + 5*n]; a6 += xk*c[k + 6*n]; a7 += xk*c[k + 7*n];
    }
    z[i] += a0; z[i+1] += a1; z[i+2] += a2; z[i+3] += a3;
    z[i+4] += a4; z[i+5] += a5; z[i+6] += a6; z[i+7] += a7;
  }
  for (; i < m; ++i) {
    casadi_real acc = 0;
    for (k = 0; k < n; ++k) acc += x[k]*y[k + i*n];
    z[i] += acc;
  }
}
""" + _ROWT_KERNEL.replace("REAL", "casadi_real")
_ROW_KERNELS_SINGLE = """
/* the same products, multiplied and summed in float (x rounded to float first) */
static void nehmo_row_f32(const casadi_real* x, casadi_int n, const float* y, casadi_int m,
    casadi_real* z) {
  float xf[NEHMO_ROW_MAX];
  casadi_int i, k;
  for (k = 0; k < n; ++k) xf[k] = (float)x[k];
  for (i = 0; i < m; ++i) {
    float acc = 0;
    for (k = 0; k < n; ++k) acc += xf[k]*y[k + i*n];
    z[i] += acc;
  }
}
""" + _ROWT_KERNEL.replace("REAL", "float")


@dataclass(frozen=True)
class _Const:
    name: str
    values: np.ndarray
    uses: list[re.Match[str]]
    shape: tuple[int, int]  # (n, m) of Y in every use


def _constants(source: str) -> dict[str, _Const]:
    """Large constants that are exactly float32, used only as the ``Y`` of row products."""
    out: dict[str, _Const] = {}
    references = Counter(re.findall(r"casadi_c\d+\b", source))
    for decl in _CONST.finditer(source):
        name, size = decl.group(1), int(decl.group(2))
        if size < COMPACT_MIN_SIZE:
            continue
        values = np.array(decl.group(3).split(","), dtype=np.float64)
        if values.size != size or not np.array_equal(values.astype(np.float32), values):
            continue
        use = re.compile(
            rf"(wr\d+) = {name};\n(\s*)casadi_mtimes_dense\((\w+), 1, (\d+), \1, (\d+), "
            rf"([^;]*?), 0\);"
        )
        uses = list(use.finditer(source))
        if not all(_pointer_dies(source, u.group(1), u.end()) for u in uses):
            continue  # the pointer is read again (e.g. a run-time transpose): it must stay
        shapes = {(int(u.group(4)), int(u.group(5))) for u in uses}
        # the #define, the declaration and one assignment per use: nothing else may read it
        if not uses or len(shapes) != 1 or references[name] != 2 + len(uses):
            continue
        ((n, m),) = shapes
        if n * m != size:
            continue
        out[name] = _Const(name, values, uses, (n, m))
    return out


def _pointer_dies(source: str, name: str, start: int) -> bool:
    """Whether pointer ``name`` is not read after ``start`` in its function (before a new
    assignment to it)."""
    end = source.find("\n}\n", start)
    end = len(source) if end < 0 else end
    at = start
    while True:
        at = source.find(name, at, end)
        if at < 0:
            return True
        after = at + len(name)
        if not (source[at - 1].isalnum() or source[at - 1] == "_") and not (
            source[after].isalnum() or source[after] == "_"
        ):
            return source.startswith(" = ", after)
        at = after


def compact_weights(source: str, single: bool = False) -> tuple[str, dict[str, int]]:
    """``source`` with its large float32-exact constants stored once as ``float`` (see above);
    ``single``: their products computed in float.

    Returns the new source and counts: ``float`` constants kept, transposed copies removed.
    """
    consts = _constants(source)
    matrices = {c.name: c.values.reshape(c.shape[1], c.shape[0]).T for c in consts.values()}
    transposed: dict[str, str] = {}  # removed constant -> the kept one it is the transpose of
    for name, c in consts.items():
        if name in transposed:
            continue
        for other, d in consts.items():
            if other == name or other in transposed or other in transposed.values():
                continue
            if d.shape == c.shape[::-1] and np.array_equal(matrices[other], matrices[name].T):
                transposed[other] = name
                break
    replacements: list[tuple[int, int, str]] = []
    rowt_max = row_max = 1
    for name, c in consts.items():
        kept = transposed.get(name)
        for u in c.uses:
            x, n, m, z = u.group(3), u.group(4), u.group(5), u.group(6)
            if kept is None:
                call = f"nehmo_row_f32({x}, {n}, {name}, {m}, {z});"
                row_max = max(row_max, int(n))
            else:
                call = f"nehmo_rowt_f32({x}, {n}, {kept}, {m}, {z});"
                rowt_max = max(rowt_max, int(m))
            replacements.append((u.start(), u.end(), u.group(2) + call))
    for decl in _CONST.finditer(source):
        name = decl.group(1)
        if name in transposed:
            replacements.append((decl.start(), decl.end(), ""))
        elif name in consts:
            text = decl.group(0).replace("static const casadi_real", "static const float", 1)
            replacements.append((decl.start(), decl.end(), text))
    if not replacements:
        return source, {"float": 0, "removed": 0}
    parts, last = [], 0
    for start, end, text in sorted(replacements):
        parts.append(source[last:start])
        parts.append(text)
        last = end
    parts.append(source[last:])
    out = "".join(parts)
    first = min(start for start, _, _ in replacements)
    head = out.rfind("\n", 0, first) + 1  # the kernels go before the first constant touched
    sizes = f"#define NEHMO_ROWT_MAX {rowt_max}\n#define NEHMO_ROW_MAX {row_max}\n"
    kernels = sizes + (_ROW_KERNELS_SINGLE if single else _ROW_KERNELS)
    out = out[:head] + kernels + out[head:]
    return out, {"float": len(consts) - len(transposed), "removed": len(transposed)}


def _key(fn: ca.Function, compiler: str, compact: bool = True, single: bool = False) -> str:
    h = hashlib.sha256()
    parts = (
        fn.serialize(),
        ca.CasadiMeta.version(),
        compiler,
        " ".join(CFLAGS),
        _CODEGEN_VERSION + ("" if compact else "-plain") + ("-single" if single else ""),
        _cpu(),
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
    compiler = _compiler()
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
