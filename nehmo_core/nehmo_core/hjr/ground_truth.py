"""Grid ground truth with ``hj_reachability`` (JAX on CPU), cached on disk, and validation.

Conventions. ``hj_reachability`` solves ``∂V/∂t + H̃ = 0`` backward from ``V(0, x) = l(x)`` over
``times = [0, −τ₁, −τ₂, …]``; with ``hamiltonian_postprocessor = backwards_reachable_tube``
(``H̃ = min(0, H)``), control mode ``"max"`` and disturbance mode ``"min"`` this is exactly our
avoid BRT in time-to-go: ``V_gt(τ, x) = values[k]`` at ``times[k] = −τ``, ``∂V/∂τ = min(0, H)``,
``V`` non-increasing in ``τ``. Values are stored in physical units (Air3D: not normalized).

Grids, in the coordinates of :mod:`nehmo_core.hjr.systems`:

- Air3D: ``x1, x2 ∈ [−1, 1]`` (endpoints included), ``x3`` periodic over one heading turn,
  ``[−1/1.2, 1/1.2)`` (``θ ∈ [−π, π)``); default 51³, τ every 0.1 s up to ``T = 1.1``.
- Two-link pair: ``q ∈ [−π, π)⁴`` periodic, default 41⁴, τ every 0.1 s up to ``T = 0.6``.

Cache: ``$NEHMO_CACHE/groundtruth`` if ``NEHMO_CACHE`` is set, else
``~/.cache/nehmo/groundtruth``; one ``.npz`` per (system parameters, grid, times, accuracy).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nehmo_core.errors import InvalidValueError, NehmoError, UnknownNameError
from nehmo_core.hjr.networks import ValueFunction
from nehmo_core.hjr.systems import Air3D, ArmPairSystem, HJISystem

__all__ = [
    "GroundTruth",
    "ValidationRow",
    "add_validate_arguments",
    "cache_dir",
    "default_grid_shape",
    "ground_truth",
    "run_validate",
    "validate",
]

ACCURACIES = ("low", "medium", "high", "very_high")


def cache_dir() -> Path:
    """Where ground truths are cached (``$NEHMO_CACHE/groundtruth`` or ``~/.cache/nehmo/...``)."""
    root = os.environ.get("NEHMO_CACHE")
    base = Path(root) if root else Path.home() / ".cache" / "nehmo"
    return base / "groundtruth"


def default_grid_shape(system: HJISystem) -> tuple[int, ...]:
    """51³ for Air3D, 41 per joint for arm pairs."""
    if isinstance(system, Air3D):
        return (51, 51, 51)
    return (41,) * system.state_dim


def _default_taus(system: HJISystem) -> np.ndarray:
    count = round(system.horizon / 0.1)
    taus = np.linspace(0.0, 0.1 * count, count + 1)
    if not math.isclose(taus[-1], system.horizon):
        taus = np.append(taus, system.horizon)
    return taus


@dataclass(frozen=True)
class GroundTruth:
    """A grid solution: ``values[k]`` is ``V(taus[k], ·)`` on the grid, physical units."""

    system_name: str
    coordinate_vectors: tuple[np.ndarray, ...]
    taus: np.ndarray  # (K,) [s]
    values: np.ndarray  # (K, *shape) float32
    solve_seconds: float

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(c) for c in self.coordinate_vectors)

    def states(self) -> np.ndarray:
        """All grid states, ``(N, n)`` in C order (matching ``values[k].reshape(-1)``)."""
        mesh = np.meshgrid(*self.coordinate_vectors, indexing="ij")
        return np.stack([m.reshape(-1) for m in mesh], axis=1)

    def index_of(self, tau: float) -> int:
        """Index of the stored ``tau`` [s]; other times raise :class:`InvalidValueError`."""
        matches = np.flatnonzero(np.isclose(self.taus, tau, atol=1e-6))
        if matches.size == 0:
            raise InvalidValueError("tau", f"must be one of the stored {self.taus.tolist()}", tau)
        return int(matches[0])

    def value_at(self, tau: float) -> np.ndarray:
        """``V(τ, ·)`` on the grid, shape ``self.shape``."""
        return self.values[self.index_of(tau)]


# ------------------------------------------------------------------------------------------------
# hj_reachability adapters
# ------------------------------------------------------------------------------------------------


def _hj_problem(system: HJISystem, shape: tuple[int, ...]) -> tuple[Any, Any]:
    """``(dynamics, grid)`` for ``hj_reachability`` in our coordinates."""
    import hj_reachability as hj
    import jax.numpy as jnp

    if isinstance(system, Air3D):
        dynamics: Any = _air3d_dynamics(system)
        half_turn = math.pi / system.angle_scale
        lo, hi = [-1.0, -1.0, -half_turn], [1.0, 1.0, half_turn]
        periodic_dims: tuple[int, ...] = (2,)
    elif isinstance(system, ArmPairSystem):
        dynamics = _arm_pair_dynamics(system)
        lo, hi = list(system.lower), list(system.upper)
        periodic_dims = tuple(i for i, p in enumerate(system.periodic) if p)
    else:
        raise UnknownNameError(
            "ground-truth system type", type(system).__name__, ["Air3D", "ArmPairSystem"]
        )
    domain = hj.sets.Box(jnp.array(lo), jnp.array(hi))
    grid = hj.Grid.from_lattice_parameters_and_boundary_conditions(
        domain, shape, periodic_dims=periodic_dims
    )
    return dynamics, grid


def _air3d_dynamics(system: Air3D) -> Any:
    import hj_reachability as hj
    import jax.numpy as jnp

    w, v, alpha = system.omega_max, system.velocity, system.angle_scale

    class _Air3DNormalized(hj.ControlAndDisturbanceAffineDynamics):
        def open_loop_dynamics(self, state: Any, time: Any) -> Any:
            theta = alpha * state[2]
            return jnp.array([-v + v * jnp.cos(theta), v * jnp.sin(theta), 0.0])

        def control_jacobian(self, state: Any, time: Any) -> Any:
            return jnp.array([[state[1]], [-state[0]], [-1.0 / alpha]])

        def disturbance_jacobian(self, state: Any, time: Any) -> Any:
            return jnp.array([[0.0], [0.0], [1.0 / alpha]])

    box = hj.sets.Box(jnp.array([-w]), jnp.array([w]))
    return _Air3DNormalized("max", "min", box, box)


def _arm_pair_dynamics(system: ArmPairSystem) -> Any:
    import hj_reachability as hj
    import jax.numpy as jnp

    n1, n2 = system.n1, system.n2
    g_u = jnp.concatenate([jnp.eye(n1), jnp.zeros((n2, n1))])
    g_d = jnp.concatenate([jnp.zeros((n1, n2)), jnp.eye(n2)])

    class _VelocityPair(hj.ControlAndDisturbanceAffineDynamics):
        def open_loop_dynamics(self, state: Any, time: Any) -> Any:
            return jnp.zeros(n1 + n2)

        def control_jacobian(self, state: Any, time: Any) -> Any:
            return g_u

        def disturbance_jacobian(self, state: Any, time: Any) -> Any:
            return g_d

    control = hj.sets.Box(-system.u_max * jnp.ones(n1), system.u_max * jnp.ones(n1))
    disturbance = hj.sets.Box(-system.d_max * jnp.ones(n2), system.d_max * jnp.ones(n2))
    return _VelocityPair("max", "min", control, disturbance)


def _boundary_on_grid(system: HJISystem, states: np.ndarray, chunk: int = 1 << 18) -> np.ndarray:
    flat = states.reshape(-1, states.shape[-1])
    with torch.no_grad():
        parts = [
            system.boundary(torch.tensor(flat[i : i + chunk], dtype=torch.float64)).numpy()
            for i in range(0, flat.shape[0], chunk)
        ]
    return np.concatenate(parts).reshape(states.shape[:-1])


def _solve(
    system: HJISystem, shape: tuple[int, ...], taus: np.ndarray, accuracy: str
) -> GroundTruth:
    import hj_reachability as hj
    import jax.numpy as jnp

    dynamics, grid = _hj_problem(system, shape)
    initial = _boundary_on_grid(system, np.asarray(grid.states))
    settings = hj.SolverSettings.with_accuracy(
        accuracy, hamiltonian_postprocessor=hj.solver.backwards_reachable_tube
    )
    start = time.perf_counter()
    values = hj.solve(
        settings, dynamics, grid, jnp.asarray(-taus), jnp.asarray(initial), progress_bar=False
    )
    values = np.asarray(values, dtype=np.float32)
    seconds = time.perf_counter() - start
    vectors = tuple(np.asarray(c, dtype=np.float64) for c in grid.coordinate_vectors)
    return GroundTruth(system.name, vectors, taus.astype(np.float64), values, seconds)


def _cache_key(system: HJISystem, shape: tuple[int, ...], taus: np.ndarray, accuracy: str) -> str:
    payload = json.dumps(
        {
            "system": system.describe(),
            "shape": list(shape),
            "taus": [round(float(t), 9) for t in taus],
            "accuracy": accuracy,
            "version": 1,
        },
        sort_keys=True,
    )
    digest = hashlib.sha256(payload.encode()).hexdigest()[:16]
    size = "x".join(str(s) for s in shape)
    return f"{system.name}_{size}_{accuracy}_{digest}.npz"


def ground_truth(
    system: HJISystem,
    grid_shape: Sequence[int] | None = None,
    taus: Sequence[float] | None = None,
    accuracy: str = "very_high",
    cache: bool = True,
    directory: str | Path | None = None,
) -> GroundTruth:
    """Solve (or load from the cache) the avoid BRT value of ``system`` on a grid.

    ``taus`` are the stored times-to-go [s] (must start at 0); default every 0.1 s up to ``T``.
    ``accuracy`` is an ``hj_reachability`` preset (``ACCURACIES``).
    """
    shape = tuple(int(s) for s in (grid_shape or default_grid_shape(system)))
    if len(shape) != system.state_dim or min(shape) < 3:
        raise InvalidValueError(
            "grid_shape", f"must have {system.state_dim} entries >= 3", list(shape)
        )
    tau_array = _default_taus(system) if taus is None else np.asarray(taus, dtype=np.float64)
    _check_taus(tau_array, system.horizon)
    if accuracy not in ACCURACIES:
        raise UnknownNameError("accuracy", accuracy, ACCURACIES)
    path = Path(directory) if directory is not None else cache_dir()
    path = path / _cache_key(system, shape, tau_array, accuracy)
    if cache and path.exists():
        return _load(path)
    result = _solve(system, shape, tau_array, accuracy)
    if cache:
        _store(path, result)
    return result


def _check_taus(taus: np.ndarray, horizon: float) -> None:
    if taus.ndim != 1 or taus.size < 1 or taus[0] != 0.0:
        raise InvalidValueError("taus", "must be a 1-D list starting at 0", taus.tolist())
    if np.any(np.diff(taus) <= 0) or taus[-1] > horizon + 1e-9:
        raise InvalidValueError("taus", f"must increase within [0, {horizon}]", taus.tolist())


def _store(path: Path, result: GroundTruth) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, Any] = {f"coords_{i}": c for i, c in enumerate(result.coordinate_vectors)}
    arrays["system_name"] = np.array(result.system_name)
    arrays["taus"] = result.taus
    arrays["values"] = result.values
    arrays["solve_seconds"] = np.array(result.solve_seconds)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def _load(path: Path) -> GroundTruth:
    with np.load(path, allow_pickle=False) as data:
        count = sum(1 for k in data.files if k.startswith("coords_"))
        vectors = tuple(data[f"coords_{i}"] for i in range(count))
        return GroundTruth(
            str(data["system_name"]),
            vectors,
            data["taus"],
            data["values"],
            float(data["solve_seconds"]),
        )


# ------------------------------------------------------------------------------------------------
# Validation
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ValidationRow:
    """Learned vs grid value at one time-to-go; volumes and fractions are shares of the grid."""

    tau: float  # [s]
    mean_abs_error: float
    max_abs_error: float
    brt_volume_learned: float  # share of states with V ≤ 0
    brt_volume_true: float
    falsely_safe: float  # V_learned > 0 where V_true ≤ 0
    falsely_unsafe: float  # V_learned ≤ 0 where V_true > 0


def validate(
    value_function: ValueFunction,
    system: HJISystem | None = None,
    taus: Sequence[float] | None = None,
    truth: GroundTruth | None = None,
) -> list[ValidationRow]:
    """Compare ``value_function`` with the grid ground truth at each ``tau`` (default: all stored).

    Errors are in the system's physical value units (Air3D: de-normalized ``V``).
    """
    system = system or value_function.system
    truth = truth or ground_truth(system)
    if truth.system_name != system.name:
        raise InvalidValueError(
            "truth", f"must be a ground truth of {system.name!r}", truth.system_name
        )
    states = truth.states()
    chosen = truth.taus if taus is None else np.asarray(taus, dtype=np.float64)
    return [_compare(value_function, states, float(t), truth) for t in chosen]


def _compare(
    value_function: ValueFunction, states: np.ndarray, tau: float, truth: GroundTruth
) -> ValidationRow:
    true = truth.value_at(tau).reshape(-1).astype(np.float64)
    learned = np.asarray(value_function.value(tau, states), dtype=np.float64)
    error = np.abs(learned - true)
    unsafe_true, unsafe_learned = true <= 0.0, learned <= 0.0
    return ValidationRow(
        tau=tau,
        mean_abs_error=float(error.mean()),
        max_abs_error=float(error.max()),
        brt_volume_learned=float(unsafe_learned.mean()),
        brt_volume_true=float(unsafe_true.mean()),
        falsely_safe=float((unsafe_true & ~unsafe_learned).mean()),
        falsely_unsafe=float((unsafe_learned & ~unsafe_true).mean()),
    )


def add_validate_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``nehmo validate`` options to ``parser``."""
    parser.add_argument("--model", required=True, help="run directory or .safetensors file")
    parser.add_argument("--taus", default=None, help="comma-separated times-to-go [s]")
    parser.add_argument("--json", default=None, help="also write the rows to this JSON file")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")


def run_validate(args: argparse.Namespace) -> int:
    """Run ``nehmo validate`` from parsed arguments; returns the process exit code."""
    from nehmo_core.hjr.model_files import load_value_function

    if args.threads is not None:
        if args.threads < 1:
            raise InvalidValueError("threads", "must be >= 1", args.threads)
        torch.set_num_threads(args.threads)
    value_function = load_value_function(args.model)
    taus = None
    if args.taus is not None:
        try:
            taus = [float(t) for t in args.taus.split(",")]
        except ValueError as exc:
            raise InvalidValueError("taus", "must be comma-separated numbers", args.taus) from exc
    rows = validate(value_function, taus=taus)
    print("tau_s  mean_abs  max_abs  brt_learned  brt_true  falsely_safe  falsely_unsafe")
    for r in rows:
        print(
            f"{r.tau:5.2f}  {r.mean_abs_error:8.4f}  {r.max_abs_error:7.4f}  "
            f"{r.brt_volume_learned:11.4f}  {r.brt_volume_true:8.4f}  "
            f"{r.falsely_safe:12.4f}  {r.falsely_unsafe:14.4f}"
        )
    if args.json is not None:
        Path(args.json).write_text(json.dumps([r.__dict__ for r in rows], indent=2) + "\n")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m nehmo_core.hjr.ground_truth --model runs/a``."""
    parser = argparse.ArgumentParser(prog="nehmo validate", description=__doc__.splitlines()[0])
    add_validate_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run_validate(args)
    except NehmoError as exc:
        parser.exit(2, f"nehmo validate: error: {exc}\n")


if __name__ == "__main__":
    raise SystemExit(main())
