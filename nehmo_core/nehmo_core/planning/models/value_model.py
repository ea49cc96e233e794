"""What a planner needs from a trained pair value function.

A :class:`PairValueModel` is the pair's geometry (robot 1 at the pair frame's origin, robot 2
at ``base2``; robot 1 is the controlled arm, robot 2 the disturbance) and two CasADi functions:
``value(tau, x) -> v`` (a graph, used by IPOPT) and ``value_grad(tau, x) -> (v, ∇ₓv)``
(generated C when a compiler works). Anything that provides these can constrain the planner;
:meth:`PairValueModel.from_value_function` builds one from a torch value function.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.hjr.casadi_export import pair_boundary, value_functions
from nehmo_core.hjr.networks import ValueFunction
from nehmo_core.planning.models.pair_frame import inverse_pose
from nehmo_core.planning.numerics.codegen import compile_function
from nehmo_core.robots.model import Pose
from nehmo_core.sim.actuators import certificate_actuators

__all__ = ["PairValueModel"]


@dataclass(frozen=True, eq=False)
class PairValueModel:
    """``V(τ, q¹, q²)`` [m] of one arm pair with CasADi evaluation, batched over peers.

    ``tau`` is time-to-go [s] in ``[0, horizon]``; ``x = (q¹, q²)`` [rad] in the pair frame.
    A pose-conditioned model (``base_range`` set) serves every base distance ``r`` [m] in that
    range, robot 2 then sitting at ``base2`` moved by ``(r, 0, 0)``; its states are
    ``x = (q¹, q², r)`` (:func:`~nehmo_core.planning.models.pair_frame.match_pair` appends ``r``).
    """

    name: str
    robot1: str
    robot2: str
    base2: Pose
    n1: int
    n2: int
    horizon: float
    value: ca.Function
    value_grad: ca.Function
    backend: str = "vm"
    library: Path | None = None  # the generated library of ``value_grad`` (compiled backend)
    certificates: tuple[dict[str, Any], ...] = ()  # from the model card (``nehmo verify``)
    base_range: tuple[float, float] | None = None  # conditioned on r in this range [m]
    _calls: dict[int, _BufferedCall] = field(default_factory=dict, repr=False)

    @property
    def state_dim(self) -> int:
        return self.n1 + self.n2 + (1 if self.base_range is not None else 0)

    @property
    def geometry(self) -> tuple[str, str, Pose, tuple[float, float] | None]:
        """What :func:`~nehmo_core.planning.models.pair_frame.match_pair` takes for this model."""
        return self.robot1, self.robot2, self.base2, self.base_range

    @classmethod
    def from_value_function(
        cls,
        value_function: ValueFunction,
        name: str = "pair_value",
        backend: str = "auto",
        single: bool = True,
    ) -> PairValueModel:
        """Export ``value_function`` (an arm-pair system with a learned-distance boundary).
        ``single``: the generated C's weight products in float (faster, ``V`` within ~1e-8;
        :mod:`~nehmo_core.planning.numerics.codegen`); ``False`` keeps them in double.

        The pair geometry comes from the distance: as trained for a plain distance; with the
        robots exchanged and the inverse base offset for a swapped one (``kinova_ur5``). A
        swapped conditioned one (``kinova_ur5_any``) keeps the base-distance range: seen from
        arm 2, arm 1 stands at ``inverse(base2)`` moved by ``(r, 0, 0)`` when ``base2`` turns
        arm 2 to face arm 1 along x (its rotation sends x to −x), which every conditioned pair
        does (:data:`~nehmo_core.geometry.distance_data.CONDITIONED_PAIRS`).
        """
        system = value_function.system
        try:
            distance, n_first = pair_boundary(system)
        except NehmoError as exc:
            raise NehmoError(
                f"value function {name!r}: {exc}, so its pair geometry (robots, base offset) "
                "is unknown"
            ) from None
        cfg = distance.config
        base2 = Pose(cfg.base2_xyz, cfg.base2_rpy)
        base_range = cfg.base2_range
        if n_first is None:
            robots, base, dofs = (cfg.robot1, cfg.robot2), base2, (distance.n1, distance.n2)
        elif base_range is not None and not _faces_back_along_x(base2):
            # (T_b·base2)⁻¹ = base2⁻¹·T_(−b) is T_b·base2⁻¹ for every shift b along x only then
            raise NehmoError(
                f"value function {name!r}: a swapped conditioned pair needs arm 2 of its "
                f"distance turned to face arm 1 along x (base2 rpy {cfg.base2_rpy} does not "
                "send x to −x), or its base distance would not shift along x seen from arm 2"
            )
        else:
            robots, base = (cfg.robot2, cfg.robot1), inverse_pose(base2)
            dofs = (distance.n2, distance.n1)
        value, value_grad = value_functions(value_function, name)
        compiled = compile_function(value_grad, backend, single=single)
        return cls(
            name=name,
            robot1=robots[0],
            robot2=robots[1],
            base2=base,
            n1=dofs[0],
            n2=dofs[1],
            horizon=float(system.horizon),
            value=value,
            value_grad=compiled.function,
            backend=compiled.backend,
            library=compiled.library,
            certificates=tuple(value_function.card.get("certificates", ())),
            base_range=None if base_range is None else (base_range[0], base_range[1]),
        )

    def certified_level(self, tau: float, actuators: str = "ideal") -> float | None:
        """The largest level ``δ`` [m] certified at time-to-go ``tau`` [s] for the actuator
        model ``actuators`` (None: none there).

        A certificate that missed its target still counts with the level it reached last, so a
        planner never trusts the model below it. Under an actuator model the ideal-tracking
        levels at ``tau`` count too: an arm that tracks worse needs no less (a distribution
        certified only with ideal tracking keeps its level).
        """
        pool = [*self.certified_for(actuators), *self.certified_for("ideal")]
        found = [c["delta"] for c in pool if abs(c["tau"] - tau) < 1e-6]
        return max(found) if found else None

    def certified_margin(self, tau: float, actuators: str = "ideal") -> float | None:
        """The level ``δ`` [m] certified at the shortest certified time-to-go ``τ_c ≥ tau`` [s]
        (the horizon itself when certified there), or None when none is that long.

        A level certified over a longer horizon is taken for a shorter one, on the premise that
        the learned value's error does not shrink with the horizon.
        """
        longer = [float(c["tau"]) for c in self.certified_for(actuators) if c["tau"] >= tau - 1e-6]
        return self.certified_level(min(longer), actuators) if longer else None

    def certified_under(self, actuators: str) -> bool:
        """Whether the card holds a certificate made under actuator model ``actuators`` (one
        that names none was made with ideal tracking)."""
        return any(certificate_actuators(c) == actuators for c in self.certificates)

    def certified_for(self, actuators: str) -> list[dict[str, Any]]:
        """The certificates made under actuator model ``actuators``; the ideal ones if the card
        has none for it."""
        name = actuators if self.certified_under(actuators) else "ideal"
        return [c for c in self.certificates if certificate_actuators(c) == name]

    def evaluate(
        self, tau: float, x: np.ndarray, own_step: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(V (k,), ∇ₓV (k, n))`` at time-to-go ``tau`` [s] for states ``x`` (k, n) [rad],
        each with ``own_step`` (n1,) [rad] added to robot 1's joints if given."""
        if not 0.0 <= tau <= self.horizon + 1e-9:
            raise InvalidValueError("tau", f"must lie in [0, {self.horizon}] s", tau)
        k = x.shape[0]
        call = self._calls.get(k)
        if call is None:
            fn = self.value_grad if k == 1 else self.value_grad.map(k)
            call = self._calls[k] = _BufferedCall(fn, k, self.state_dim)
        return call(tau, x, own_step)


def _faces_back_along_x(pose: Pose) -> bool:
    """Whether ``pose``'s rotation sends the x axis to −x (arm 2 facing arm 1 along x)."""
    return bool(np.allclose(pose.matrix()[:3, 0], (-1.0, 0.0, 0.0), atol=1e-9))


class _BufferedCall:
    """Zero-copy evaluation of ``value_grad`` mapped over ``k`` states (CasADi ``buffer()``).

    Arrays bound once; each call copies the inputs in and the outputs out (~0.1 ms less
    overhead per call than converting to and from CasADi matrices). Not thread-safe.
    """

    def __init__(self, fn: ca.Function, k: int, n: int) -> None:
        self.fn = fn
        self.tau = np.zeros(k)
        self.x = np.zeros((k, n))  # row-major (k, n) is column-major (n, k): CasADi's layout
        self.v = np.zeros(k)
        self.g = np.zeros((k, n))
        self.buffer, self.trigger = fn.buffer()
        buffer: Any = self.buffer  # the stubs ask for a size the binding does not take
        buffer.set_arg(0, memoryview(self.tau))  # type: ignore[arg-type]
        buffer.set_arg(1, memoryview(self.x))  # type: ignore[arg-type]
        buffer.set_res(0, memoryview(self.v))  # type: ignore[arg-type]
        buffer.set_res(1, memoryview(self.g))  # type: ignore[arg-type]

    def __call__(
        self, tau: float, x: np.ndarray, own_step: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        self.tau[:] = tau
        self.x[:] = x
        if own_step is not None:
            self.x[:, : len(own_step)] += own_step
        self.trigger()
        if self.buffer.ret() != 0:
            raise NehmoError(f"evaluation of {self.fn.name()} failed (status {self.buffer.ret()})")
        return self.v.copy(), self.g.copy()
