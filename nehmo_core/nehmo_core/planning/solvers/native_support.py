"""What the C SQP loop (``sqp_loop.c``) needs besides its Python class: the compiled library
(built once per source, compiler and CPU, cached beside the generated model code), the check of
its DAQP interface against ``daqp.solve``, and the memory it shares with Python: the ctypes view
of a group of V rows, a model's loaded C function with its work arrays, and the fixed-size
buffers of one solve (allocated once; a solve copies its inputs in). Used by
:mod:`nehmo_core.planning.solvers.native`.
"""

from __future__ import annotations

import ctypes
import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.numerics.codegen import compile_library, cpu_signature, find_compiler
from nehmo_core.planning.numerics.qp import qp_step
from nehmo_core.robots.loader import cache_dir

SOURCE = Path(__file__).with_name("sqp_loop.c")
CFLAGS = ("-O2", "-march=native", "-fno-math-errno", "-fPIC", "-shared")
MAX_N, MAX_M = 16, 64  # NEHMO_MAX_N, NEHMO_MAX_M in the C file

_P = ctypes.c_void_p
_D = ctypes.c_double
_I = ctypes.c_int


class RowGroup(ctypes.Structure):
    _fields_ = [
        ("fn", _P),
        ("iw", _P),
        ("w", _P),
        ("n", _I),
        ("k", _I),
        ("states", _P),
        ("x", _P),
        ("g", _P),
        ("arg", _P),
        ("res", _P),
        ("tau", _D),
        ("eps", _D),
    ]


@dataclass(frozen=True)
class Prepared:
    """The arguments of ``nehmo_sqp_iterate`` fixed by the constraints, and their memory."""

    fixed: tuple[object, ...]  # groups, group structs, nlin, A, b
    structs: ctypes.Array[RowGroup]
    alive: list[np.ndarray]
    m: int


@dataclass
class ModelHandle:
    """A pair model's generated V/∇V function: its C pointer and work arrays."""

    library: ctypes.CDLL  # kept alive with the pointer
    fn: int
    iw: np.ndarray
    w: np.ndarray
    x: np.ndarray
    g: np.ndarray
    arg: np.ndarray  # sz_arg pointer slots
    res: np.ndarray  # sz_res pointer slots

    addresses: tuple[int, ...] = field(init=False)  # of iw, w, x, g, arg, res

    def __post_init__(self) -> None:
        # read once: each ``.ctypes.data`` costs about a microsecond
        arrays = (self.iw, self.w, self.x, self.g, self.arg, self.res)
        self.addresses = tuple(a.ctypes.data for a in arrays)


class SolveBuffers:
    """The arrays ``nehmo_sqp_solve`` reads and writes, allocated once at the C loop's sizes
    (their addresses too): a solve copies its inputs in rather than converting each one."""

    def __init__(self) -> None:
        n, m = MAX_N, MAX_M
        self.vectors = np.zeros((4, n))  # error0, start, naive and y (out)
        self.c0, self.c = np.zeros(m), np.zeros(m)
        self.J0 = np.zeros(m * n)
        self.B0, self.B = np.zeros(n * n), np.zeros(n * n)
        self.keep = np.zeros(m, dtype=np.uint8)
        self.ints = (ctypes.c_int * 2)()  # iterations, QP flag
        rows = self.vectors.ctypes.data
        self.e0_at, self.start_at, self.naive_at, self.y_at = (rows + 8 * n * i for i in range(4))
        self.c0_at, self.c_at = self.c0.ctypes.data, self.c.ctypes.data
        self.J0_at = self.J0.ctypes.data
        self.B0_at, self.B_at = self.B0.ctypes.data, self.B.ctypes.data
        self.keep_at = self.keep.ctypes.data
        self.ints_at = ctypes.addressof(self.ints)
        self.flag_at = self.ints_at + ctypes.sizeof(ctypes.c_int)


def library_path() -> Path | None:
    """The compiled C loop (built now if this source, compiler and CPU have none yet); None
    without a C compiler."""
    cc = find_compiler()
    if cc is None:
        return None
    source = SOURCE.read_bytes()
    key = hashlib.sha256(
        b"\0".join([source, cc.encode(), " ".join(CFLAGS).encode(), cpu_signature().encode()])
    ).hexdigest()[:20]
    target = cache_dir() / "casadi" / f"nehmo_sqp_loop_{key}.so"
    if not target.exists():
        compile_library(SOURCE, target, cc, CFLAGS)
    return target


def check_qp(native: Any) -> str | None:
    """Compare ``native``'s C QP path (a loaded
    :class:`~nehmo_core.planning.solvers.native.NativeLoop`) with ``daqp.solve`` (via
    :func:`~nehmo_core.planning.numerics.qp.qp_step`); a reason if they differ."""
    rng = np.random.default_rng(7)
    for trial in range(12):
        n, m = 6 + trial % 2, 1 + trial % 4
        L = rng.standard_normal((n, n))
        B = L @ L.T + n * np.eye(n)
        grad = rng.standard_normal(n)
        J = rng.standard_normal((m, n))
        c = rng.uniform(-0.3, 0.1, m) if trial < 10 else np.full(m, -5.0)
        lo, hi = -0.1 * np.ones(n), 0.1 * np.ones(n)
        if trial >= 10:
            J[:] = 0.0
            J[:, 0] = 1.0  # c + p₀ ≥ 0 needs p₀ ≥ 5 > hi: infeasible
        ref = qp_step(B, grad, c, J, lo, hi)
        p, lam, flag = native.qp(B, grad, c, J, lo, hi)
        if flag != ref.flag:
            return f"DAQP flag {flag} against daqp.solve's {ref.flag} (trial {trial})"
        if ref.feasible and (np.abs(p - ref.p).max() > 1e-10 or np.abs(lam - ref.lam).max() > 1e-8):
            return f"QP solution differs from daqp.solve's (trial {trial})"
    return None


def load_model(model: PairValueModel) -> ModelHandle | None:
    """The C handle of ``model``'s generated V/∇V (its library loaded, work arrays sized),
    or ``None`` when it has no compiled library with the expected interface."""
    handle = None
    if model.library is not None and model.backend == "compiled":
        lib = ctypes.CDLL(str(model.library))
        name = model.value_grad.name()
        size = getattr(lib, f"{name}_casadi_int_size")
        size.restype = ctypes.c_int
        if size() == 8:
            work = getattr(lib, f"{name}_work")
            sizes = [ctypes.c_longlong() for _ in range(4)]
            if work(*[ctypes.byref(s) for s in sizes]) == 0:
                n_arg, n_res, n_iw, n_w = (int(s.value) for s in sizes)
                if n_arg >= 2 and n_res >= 2:
                    fn = ctypes.cast(getattr(lib, name), _P).value
                    n = model.state_dim
                    handle = ModelHandle(
                        lib,
                        int(fn or 0),
                        np.zeros(max(n_iw, 1), dtype=np.int64),
                        np.zeros(max(n_w, 1)),
                        np.zeros(n),
                        np.zeros(n),
                        np.zeros(n_arg, dtype=np.uintp),
                        np.zeros(n_res, dtype=np.uintp),
                    )
    return handle
