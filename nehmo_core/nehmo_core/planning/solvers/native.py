"""The SQP iterations in C (``sqp_loop.c``): the same algorithm as the Python loop, less overhead.

Why: each SQP iteration costs one V/∇V evaluation (generated C, ~0.1–0.15 ms for one pair) and,
in Python, about as much again in small-array bookkeeping (QP set-up and DAQP's Python wrapper,
BFGS, line search). The C loop calls the pair models' generated V/∇V functions and DAQP's C entry
point (``daqp_quadprog``, exported by the installed ``daqp`` module) directly, so an iteration
costs little more than its evaluation: on 79 constrained dual-UR5 problems from closed loops,
a solve took 0.76 ms at the median and 1.03 ms at p95 against 1.03 and 1.53 ms in Python, with
the same statuses and iteration counts and steps within 1e-12 rad. The screening rounds and the
restarts of :func:`.sqp.solve_sqp` run in the same call (``nehmo_sqp_solve``): each round or
restart through Python cost ~0.05–0.1 ms of its own, as much as an evaluation.

The C file is compiled with the system compiler once and cached beside the generated model
code (:mod:`.codegen`). Loading checks DAQP's C interface against ``daqp.solve`` on a few QPs
(the C side declares DAQP's structs itself); if the compiler, a model library or that check is
missing or fails, :func:`loop` returns ``None`` and the SQP runs its Python loop (same answers).
"""

from __future__ import annotations

import ctypes
import subprocess
import threading
import warnings
import weakref
from functools import cache
from typing import cast

import daqp
import numpy as np

from nehmo_core.errors import NehmoError
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.opt.problem import OptProblem
from nehmo_core.planning.solvers.native_support import (
    _D,
    _I,
    _P,
    MAX_M,
    MAX_N,
    ModelHandle,
    Prepared,
    RowGroup,
    SolveBuffers,
    check_qp,
    library_path,
    load_model,
)

__all__ = ["STATUSES", "NativeLoop", "loop"]

STATUSES = ("optimal", "infeasible", "iteration_limit", "timeout", "failed", "evaluation error")


class NativeLoop:
    """The loaded C loop, DAQP's C entry point and its default settings.

    Each thread has its own solve buffers, but each pair model has one set of scratch arrays
    (as its buffered Python evaluation has): solves that share a pair model must not overlap
    (one planner's never do; planners in several threads need models of their own)."""

    def __init__(self, library: ctypes.CDLL) -> None:
        self.library = library
        dq = ctypes.CDLL(daqp.__file__)
        self._daqp = dq
        self.quadprog = ctypes.cast(dq.daqp_quadprog, _P).value
        self.settings = ctypes.create_string_buffer(1024)  # DAQPSettings is ~150 bytes
        dq.daqp_default_settings(self.settings)
        self.settings_at = ctypes.addressof(self.settings)
        self.iterate_fn = library.nehmo_sqp_iterate
        self.iterate_fn.restype = _I
        self.iterate_fn.argtypes = [_I, _I, _P, _D, _I, _P, _I, _P, _P, _P, _P, _P, _P]
        self.iterate_fn.argtypes += [_I, _D, _D, _I, _D, _P, _P, _P, _P]
        self.solve_fn = library.nehmo_sqp_solve
        self.solve_fn.restype = _I
        self.solve_fn.argtypes = [_I, _I, _P, _D, _I, _P, _I, _P, _P, _P, _P, _P, _P]
        self.solve_fn.argtypes += [_P, _P, _D, _D, _D, _I, _D, _P, _P, _P, _P, _P, _P, _P]
        self.qp_fn = library.nehmo_qp_check
        self.qp_fn.restype = _I
        self.qp_fn.argtypes = [_P, _P, _I, _I, _P, _P, _P, _P, _P, _P, _P, _P]
        self._models: weakref.WeakKeyDictionary[PairValueModel, ModelHandle | None] = (
            weakref.WeakKeyDictionary()
        )
        self._local = threading.local()  # per thread: its SolveBuffers

    def qp(
        self,
        B: np.ndarray,
        grad: np.ndarray,
        c: np.ndarray,
        J: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """One QP through the C path: ``(p, lam, DAQP flag)`` as :func:`.qp.qp_step`."""
        n, m = len(grad), len(c)
        B, grad, c = (np.array(a, dtype=np.float64, order="C") for a in (B, grad, c))
        J, lo, hi = (np.array(a, dtype=np.float64, order="C") for a in (J, lo, hi))
        p, lam = np.zeros(n), np.zeros(m)
        args = [a.ctypes.data for a in (B, grad, c, J, lo, hi, p, lam)]
        flag = self.qp_fn(self.quadprog, ctypes.addressof(self.settings), n, m, *args)
        return p, lam, int(flag)

    def model(self, model: PairValueModel) -> ModelHandle | None:
        """The C handle of ``model``'s V/∇V, or ``None`` if it has no generated library."""
        if model in self._models:
            return self._models[model]
        handle = load_model(model)
        self._models[model] = handle
        return handle

    def _prepare(self, problem: OptProblem) -> Prepared | None:
        """The C side's view of ``problem``'s constraints (kept on them: the restarts of one
        solve reuse it), or ``None`` when a model has no C handle or the problem is too big."""
        cons = problem.constraints
        scratch = cons.scratch
        if "native" in scratch:
            return cast("Prepared | None", scratch["native"])
        models, groups, linear = cons.models, cons.groups, cons.linear
        n = len(problem.error0)  # the C loop's sizes bound n and m
        structs = (RowGroup * max(len(groups), 1))()
        alive: list[np.ndarray] = []  # arrays the C side reads, kept referenced with the structs
        m = 0
        prepared: Prepared | None = None
        for g, (slot, (index, states)) in enumerate(zip(structs, groups, strict=False)):
            handle = self.model(models[index])
            if handle is None:
                break
            states = np.ascontiguousarray(states, dtype=np.float64)
            alive.append(states)
            k, n_state = states.shape
            slot.fn, slot.n, slot.k, slot.states = handle.fn, n_state, k, states.ctypes.data
            slot.iw, slot.w, slot.x, slot.g, slot.arg, slot.res = handle.addresses
            slot.tau, slot.eps = cons.horizon(g), cons.margin(g)
            m += k
        else:
            nlin, A, b = 0, None, None
            if linear is not None:
                A = np.ascontiguousarray(linear.A, dtype=np.float64)
                b = np.ascontiguousarray(linear.b, dtype=np.float64)
                alive += [A, b]
                nlin = len(b)
            m += nlin
            if n <= MAX_N and m <= MAX_M:
                fixed: tuple[object, ...] = (len(groups),)
                fixed += (ctypes.addressof(structs), nlin)
                fixed += (A.ctypes.data if A is not None else None,)
                fixed += (b.ctypes.data if b is not None else None,)
                prepared = Prepared(fixed, structs, alive, m)
        scratch["native"] = prepared
        return prepared

    def iterate(
        self,
        problem: OptProblem,
        y: np.ndarray,
        B: np.ndarray,
        tol: float,
        max_iter: int,
        deadline: float,
        feasibility_tol: float,
        start_values: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[str, int, np.ndarray, np.ndarray, np.ndarray, int] | None:
        """Run the C loop on ``problem`` from ``y`` with Hessian approximation ``B``;
        ``(status, iterations, y, B, c, QP flag)``, or ``None`` when a model has no C handle or
        the problem exceeds the C loop's sizes. ``start_values``: the rows' ``(c, J)`` at ``y``,
        when the caller has them (saves the first evaluation)."""
        prepared = self._prepare(problem)
        if prepared is None:
            return None
        n, m = len(y), prepared.m
        e0 = np.ascontiguousarray(problem.error0, dtype=np.float64)
        y = np.array(y, dtype=np.float64)
        B = np.array(B, dtype=np.float64, order="C")
        if start_values is None:
            c, J, evaluated = np.empty(m), np.empty((m, n)), 0
        else:
            c = np.array(start_values[0], dtype=np.float64)
            J = np.array(start_values[1], dtype=np.float64, order="C")
            evaluated = 1
        iterations, flag = ctypes.c_int(), ctypes.c_int()
        code = self.iterate_fn(
            n,
            m,
            e0.ctypes.data,
            problem.y_max,
            *prepared.fixed,
            y.ctypes.data,
            B.ctypes.data,
            c.ctypes.data,
            J.ctypes.data,
            evaluated,
            tol,
            feasibility_tol,
            max_iter,
            deadline,
            self.quadprog,
            ctypes.addressof(self.settings),
            ctypes.byref(iterations),
            ctypes.byref(flag),
        )
        if code == 5:
            raise NehmoError("evaluation of a pair model's V/∇V failed in the SQP loop")
        return STATUSES[code], iterations.value, y, B, c, flag.value

    def solve(
        self,
        problem: OptProblem,
        y_start: np.ndarray,
        naive: np.ndarray,
        naive_values: tuple[np.ndarray, np.ndarray],
        B: np.ndarray,
        keep: np.ndarray,
        screen: float | None,
        tol: float,
        max_iter: int,
        deadline: float,
        feasibility_tol: float,
    ) -> tuple[str, int, np.ndarray, np.ndarray, np.ndarray | None, int] | None:
        """:func:`.sqp.solve_sqp` after its naive-step check, in one C call: the screened
        iterations from ``y_start`` (in the box) and the restarts from the naive step (whose
        rows' ``naive_values`` are at hand) and from ``y = 0``. ``(status, iterations, y, c,
        Hessian estimate or None, QP flag)``, or ``None`` when a model has no C handle or the
        problem exceeds the C loop's sizes."""
        prepared = self._prepare(problem)
        if prepared is None:
            return None
        io = getattr(self._local, "io", None)
        if io is None:
            io = self._local.io = SolveBuffers()
        n, m = len(y_start), prepared.m
        rows = problem.constraints.value_count
        io.vectors[0, :n] = problem.error0
        io.vectors[1, :n] = y_start
        io.vectors[2, :n] = naive
        io.c0[:m] = naive_values[0]
        io.J0[: m * n] = naive_values[1].reshape(-1)
        io.B0[: n * n] = B.reshape(-1)
        io.keep[:rows] = keep
        ngroups, groups, nlin, A, b = prepared.fixed
        code = self.solve_fn(
            n,
            rows,
            io.e0_at,
            problem.y_max,
            ngroups,
            groups,
            nlin,
            A,
            b,
            io.start_at,
            io.naive_at,
            io.c0_at,
            io.J0_at,
            io.B0_at,
            io.keep_at,
            np.inf if screen is None else screen,
            tol,
            feasibility_tol,
            max_iter,
            deadline,
            self.quadprog,
            self.settings_at,
            io.y_at,
            io.c_at,
            io.B_at,
            io.ints_at,
            io.flag_at,
        )
        if code == 5:
            raise NehmoError("evaluation of a pair model's V/∇V failed in the SQP loop")
        hessian = io.B[: n * n].reshape(n, n).copy() if code == 0 else None
        y, c = io.vectors[3, :n].copy(), io.c[:m].copy()
        return STATUSES[code], io.ints[0], y, c, hessian, io.ints[1]


@cache
def loop() -> NativeLoop | None:
    """The C SQP loop, compiled and checked once per process; ``None`` if unavailable."""
    try:
        target = library_path()
        if target is None:
            return None
        native = NativeLoop(ctypes.CDLL(str(target)))
        reason = check_qp(native)
    except (OSError, AttributeError, subprocess.CalledProcessError) as exc:
        reason = getattr(exc, "stderr", "") or str(exc)
    if reason:
        warnings.warn(
            f"the SQP's C loop is unavailable ({reason.strip()[:200]}); using the Python loop",
            RuntimeWarning,
            stacklevel=2,
        )
        return None
    return native
