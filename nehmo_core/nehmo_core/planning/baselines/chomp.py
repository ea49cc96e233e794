"""CHOMP as a centralized planner over the joint trajectories of all arms of a cell.

The settings are MoveIt 2's CHOMP defaults, with two exceptions that follow the paper's
CHOMP baseline: continuous joints are not unwrapped to the shortest angle (the paper wraps them
neither for NeHMO nor for CHOMP, § V; MoveIt does: ``wrap_continuous=True``), and the planning
time limit counts the process's CPU time, so a loaded machine does not cut plans short. The
trajectory of every joint of every arm has ``waypoints`` points over ``duration`` seconds, start
and goal fixed, initialized by a minimum-jerk (quintic) profile.

- Smoothness: squared accelerations by the rule ``[0, −1, 16, −30, 16, −1, 0]/12`` on the
  trajectory padded with copies of its end points: ``½ξᵀAξ + bᵀξ`` per joint, ``A = KᵀK``
  (+ ``ridge_factor·I``), in waypoint units as MoveIt's matrix (no ``dt`` scaling).
- Obstacles: each arm's body is a chain of spheres along its links (from FK; the links and
  the radius are the robot's, ``robot.facts``); another arm's spheres are its obstacles. With
  clearance ``ε`` and ``d`` the sphere-sphere distance, the potential is 0 for ``d ≥ ε``,
  ``(d − ε)²/(2ε)`` for ``0 ≤ d < ε``, ``ε/2 − d`` for ``d < 0``; its functional gradient is
  CHOMP's, weighted by sphere speed with the curvature term: ``Jᵀ‖ẋ‖[(I − x̂x̂ᵀ)∇c − cκ]``.
- Update ``Δξ = −lr·A⁻¹(w_s·∇smooth + w_o·∇obs)``, each joint's increment scaled down to at most
  ``joint_update_limit``; stop after ``max_iterations``, or ``max_iterations_after_collision_free``
  iterations after the sphere model first reports no potential above ``collision_threshold``, or
  at ``planning_time_limit`` seconds of CPU time.
- The result is checked exactly on the arms' collision geometry (PyBullet), at the waypoints and
  between them, arm against arm and each arm against itself. The obstacle cost models only the
  other arms, so a trajectory may fold an arm into itself; the check reports it (Table II's
  CHOMP collisions on dual UR5 are all of this kind).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch

from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.model import Cell, wrap_angle

__all__ = ["ChompResult", "ChompSettings", "plan_chomp"]

_ACCEL_RULE = np.array([0.0, -1.0, 16.0, -30.0, 16.0, -1.0, 0.0]) / 12.0


@dataclass(frozen=True)
class ChompSettings:
    """MoveIt 2 CHOMP defaults; ``waypoints`` over ``duration`` [s]. ``planning_time_limit`` is
    CPU time [s]; ``wrap_continuous`` aims continuous joints at the goal's nearest turn
    (MoveIt), off by default as in the paper's baseline."""

    planning_time_limit: float = 10.0
    max_iterations: int = 200
    max_iterations_after_collision_free: int = 5
    smoothness_cost_weight: float = 0.1
    obstacle_cost_weight: float = 1.0
    learning_rate: float = 0.01
    ridge_factor: float = 0.0
    joint_update_limit: float = 0.1
    collision_clearance: float = 0.2
    collision_threshold: float = 0.07
    waypoints: int = 101
    duration: float = 3.0
    check_substeps: int = 4  # exact checks between consecutive waypoints
    wrap_continuous: bool = False

    def __post_init__(self) -> None:
        if self.waypoints < 3:
            raise InvalidValueError("waypoints", "must be >= 3", self.waypoints)
        for name in ("duration", "learning_rate", "joint_update_limit", "collision_clearance"):
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))


@dataclass(frozen=True)
class ChompResult:
    """Waypoints per arm (W, dof), timing, iterations and the exact collision check."""

    waypoints: Mapping[str, np.ndarray]
    plan_time: float
    iterations: int
    collision_free: bool  # exact check on the collision geometry


def _smoothness(n: int, ridge: float) -> tuple[np.ndarray, np.ndarray]:
    """``(K, A)``: acceleration rows on the padded trajectory, ``A = KᵀK`` on free points."""
    pad = 3
    total = n + 2 * pad
    K = np.zeros((total - 6, total))
    for i in range(total - 6):
        K[i, i : i + 7] = _ACCEL_RULE
    free = K[:, pad + 1 : pad + n - 1]
    return K, free.T @ free + ridge * np.eye(n - 2)


class _Bodies:
    """Sphere centres (W, S, 3) and their Jacobians (W, S, 3, dof) for one arm."""

    def __init__(self, cell: Cell, arm_id: str) -> None:
        arm = cell.arm(arm_id)
        self.kin = ArmKinematics(arm.robot, arm.base)
        self.radius = arm.robot.facts.sphere_radius  # [m], covering each link's section
        self.links: list[str] = list(arm.robot.facts.keypoints or self.kin.link_names)
        self.dof = arm.robot.dof

    def centres(self, q: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            pts = self.kin.link_positions(torch.from_numpy(q), tuple(self.links)).numpy()
        parts = []
        for i in range(pts.shape[1] - 1):
            a, b = pts[:, i], pts[:, i + 1]
            k = max(1, int(np.ceil(np.linalg.norm(b - a, axis=-1).max() / self.radius)))
            for s in np.arange(k) / k:
                parts.append((1 - s) * a + s * b)
        parts.append(pts[:, -1])
        return np.stack(parts, axis=1)

    def centres_and_jacobians(self, q: np.ndarray, h: float = 1e-6) -> tuple[np.ndarray, ...]:
        w = q.shape[0]
        batch = np.repeat(q[:, None, :], self.dof + 1, axis=1)
        batch[:, 1:, :] += h * np.eye(self.dof)[None]
        c = self.centres(batch.reshape(-1, self.dof)).reshape(w, self.dof + 1, -1, 3)
        jac = (c[:, 1:] - c[:, :1]) / h  # (W, dof, S, 3)
        return c[:, 0], jac.transpose(0, 2, 3, 1)


def _potential(d: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """CHOMP's obstacle cost and its derivative in the distance ``d`` [m]."""
    cost = np.where(d < 0, eps / 2 - d, np.where(d < eps, (d - eps) ** 2 / (2 * eps), 0.0))
    slope = np.where(d < 0, -1.0, np.where(d < eps, (d - eps) / eps, 0.0))
    return cost, slope


def _obstacle_gradient(
    bodies: list[_Bodies], trajs: list[np.ndarray], dt: float, eps: float
) -> tuple[list[np.ndarray], float]:
    """CHOMP's obstacle gradient per arm (W, dof) and the largest potential of any sphere."""
    data = [b.centres_and_jacobians(t) for b, t in zip(bodies, trajs, strict=True)]
    grads, worst = [], 0.0
    for i, (centres, jac) in enumerate(data):
        cost = np.zeros(centres.shape[:2])
        dcost = np.zeros(centres.shape)
        for j, (other, _) in enumerate(data):
            if j == i:
                continue
            diff = centres[:, :, None, :] - other[:, None, :, :]
            dist = np.linalg.norm(diff, axis=-1)
            d = dist - bodies[i].radius - bodies[j].radius
            c, s = _potential(d, eps)
            cost += c.sum(axis=2)
            dcost += (s[..., None] * diff / np.maximum(dist, 1e-9)[..., None]).sum(axis=2)
        worst = max(worst, float(cost.max()))
        vel = np.gradient(centres, dt, axis=0)
        acc = np.gradient(vel, dt, axis=0)
        speed = np.linalg.norm(vel, axis=-1, keepdims=True)
        unit = vel / np.maximum(speed, 1e-9)
        proj = np.eye(3) - unit[..., :, None] * unit[..., None, :]
        kappa = np.einsum("wsij,wsj->wsi", proj, acc) / np.maximum(speed, 1e-9) ** 2
        force = speed * (np.einsum("wsij,wsj->wsi", proj, dcost) - cost[..., None] * kappa)
        grads.append(np.einsum("wsid,wsi->wd", jac, force))
    return grads, worst


def _initial(start: np.ndarray, goal: np.ndarray, n: int) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)[:, None]
    return start + (goal - start) * (10 * s**3 - 15 * s**4 + 6 * s**5)


def _collision_free(world: CellWorld, cell: Cell, trajs: list[np.ndarray], substeps: int) -> bool:
    for w in range(trajs[0].shape[0] - 1):
        for s in np.arange(substeps) / substeps:
            world.set_configuration(
                {
                    a.arm_id: (1 - s) * t[w] + s * t[w + 1]
                    for a, t in zip(cell.arms, trajs, strict=True)
                }
            )
            if world.in_collision():
                return False
    world.set_configuration({a.arm_id: t[-1] for a, t in zip(cell.arms, trajs, strict=True)})
    return not world.in_collision()


def plan_chomp(
    cell: Cell,
    start: Mapping[str, np.ndarray],
    goal: Mapping[str, np.ndarray],
    settings: ChompSettings | None = None,
    world: CellWorld | None = None,
) -> ChompResult:
    """Optimize all arms' trajectories from ``start`` to ``goal`` jointly (centralized)."""
    s = settings or ChompSettings()
    t0, cpu0 = time.perf_counter(), time.process_time()
    n, dt = s.waypoints, s.duration / (s.waypoints - 1)
    K, A = _smoothness(n, s.ridge_factor)
    A_inv = np.linalg.inv(A)
    trajs, bodies = [], []
    for arm in cell.arms:
        q0 = arm.robot.check_q(start[arm.arm_id], f"start[{arm.arm_id!r}]")
        qg = arm.robot.check_q(goal[arm.arm_id], f"goal[{arm.arm_id!r}]")
        if s.wrap_continuous:
            qg = np.where(arm.robot.continuous, q0 + wrap_angle(qg - q0), qg)
        trajs.append(_initial(q0, qg, n))
        bodies.append(_Bodies(cell, arm.arm_id))
    free_since, iteration = -1, 0
    for iteration in range(1, s.max_iterations + 1):
        obstacle, worst = _obstacle_gradient(bodies, trajs, dt, s.collision_clearance)
        if worst < s.collision_threshold and free_since < 0:
            free_since = iteration
        if free_since >= 0 and iteration - free_since >= s.max_iterations_after_collision_free:
            break
        if time.process_time() - cpu0 > s.planning_time_limit:
            break
        for k, traj in enumerate(trajs):
            padded = np.concatenate([np.repeat(traj[:1], 3, 0), traj, np.repeat(traj[-1:], 3, 0)])
            smooth = (K.T @ (K @ padded))[4 : 4 + n - 2]
            grad = s.smoothness_cost_weight * smooth + s.obstacle_cost_weight * obstacle[k][1:-1]
            step = -s.learning_rate * (A_inv @ grad)
            scale = np.maximum(1.0, np.abs(step).max(axis=0) / s.joint_update_limit)
            traj[1:-1] += step / scale
    own_world = world is None
    w = world if world is not None else CellWorld(cell)
    try:
        free = _collision_free(w, cell, trajs, s.check_substeps)
    finally:
        if own_world:
            w.close()
    waypoints = {a.arm_id: t for a, t in zip(cell.arms, trajs, strict=True)}
    return ChompResult(waypoints, time.perf_counter() - t0, iteration, free)
