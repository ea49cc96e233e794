"""Compact weights in generated C: each large weight matrix stored once, as ``float`` when
exact, multiplied through by two row kernels (one reads it transposed).

CasADi writes every weight matrix twice (``W`` for the forward pass, ``Wᵀ`` for the gradient) as
doubles; :func:`compact_weights` rewrites the generated source so that each matrix of at least
:data:`COMPACT_MIN_SIZE` entries whose values are all float32 is kept once as ``float`` and its
products go through the kernels below (double arithmetic; with ``single=True`` float). A
constant whose uses do not match the expected pattern is left as it is. Used by
:mod:`nehmo_core.planning.numerics.codegen`.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass

import numpy as np

__all__ = ["COMPACT_MIN_SIZE", "compact_weights"]

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
