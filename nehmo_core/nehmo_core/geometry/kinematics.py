"""Batched forward kinematics from a robot's URDF.

The URDF is parsed by pytorch-kinematics; :class:`ArmKinematics` flattens the serial chain into
a list of fixed transforms and joint axes and evaluates it with plain batched tensor products, so
it is cheap at batch 1 (the planner) and differentiable (autograd) at any batch size. Frames:
``T_world_link`` maps link coordinates to world coordinates; the world frame is the cell's.
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pytorch_kinematics as pk
import torch

from nehmo_core.robots.model import Pose, RobotModel


@dataclass(frozen=True)
class _Step:
    link: str  # child link of this step
    T_parent_joint: torch.Tensor  # (4, 4) fixed origin transform
    axis: torch.Tensor | None  # (3,) unit axis for a revolute joint, None for fixed
    q_index: int  # index into the joint vector, -1 for fixed


@dataclass(frozen=True)
class _Constants:
    T_world_base: torch.Tensor  # (4, 4)
    T_parent_joint: list[torch.Tensor]  # (4, 4) per step
    K: list[torch.Tensor | None]  # (3, 3) skew matrix of the axis per revolute step
    K2: list[torch.Tensor | None]  # K @ K


def _skew(axis: torch.Tensor) -> torch.Tensor:
    x, y, z = axis.tolist()
    return torch.tensor([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]], dtype=axis.dtype)


@contextlib.contextmanager
def _quiet_urdf_parser() -> Iterator[None]:
    """pytorch-kinematics' URDF parser writes a line per attribute it does not model (e.g. the
    Panda's ``dynamics`` friction terms): none of them matters for kinematics; drop them."""
    core = importlib.import_module("pytorch_kinematics.urdf_parser_py.xml_reflection.core")
    before = getattr(core, "on_error")  # noqa: B009 (the module is untyped)
    setattr(core, "on_error", lambda message: None)  # noqa: B010
    try:
        yield
    finally:
        setattr(core, "on_error", before)  # noqa: B010


class ArmKinematics:
    """Forward kinematics of one arm at a base pose.

    ``link_transforms(q)`` with ``q`` of shape (B, dof) returns ``T_world_link`` (B, 4, 4) for
    every link of the chain (root to tip, including fixed links).
    """

    def __init__(
        self, robot: RobotModel, base: Pose | None = None, dtype: torch.dtype = torch.float64
    ) -> None:
        self.robot = robot
        self.dtype = dtype
        with _quiet_urdf_parser():
            chain = pk.build_serial_chain_from_urdf(
                robot.urdf_path.read_bytes(), robot.tip_link, robot.root_link
            ).to(dtype=dtype)
        self.pk_chain = chain
        names = list(robot.joint_names)
        self.T_world_base = torch.as_tensor((base or Pose()).matrix(), dtype=dtype)
        steps: list[_Step] = []
        for frame in chain._serial_frames:  # root → tip, one frame per child link
            if frame.link.name == robot.root_link:
                continue
            joint = frame.joint
            T = joint.offset.get_matrix()[0] if joint.offset is not None else torch.eye(4)
            T = T.to(dtype)
            if joint.joint_type == "fixed":
                steps.append(_Step(frame.link.name, T, None, -1))
            elif joint.joint_type == "revolute":
                axis = joint.axis.to(dtype)
                steps.append(_Step(frame.link.name, T, axis / axis.norm(), names.index(joint.name)))
            else:
                raise NotImplementedError(f"joint type {joint.joint_type!r}")
        self._steps = steps
        self.root_link = robot.root_link
        self.link_names: tuple[str, ...] = (robot.root_link, *[s.link for s in steps])
        self._K = [(_skew(s.axis) if s.axis is not None else None) for s in steps]
        self._const_cache: dict[tuple[torch.dtype, torch.device], _Constants] = {}

    def _constants(self, dtype: torch.dtype, device: torch.device) -> _Constants:
        """The chain's fixed tensors in ``dtype`` on ``device`` (converted once, then cached)."""
        key = (dtype, device)
        if key not in self._const_cache:
            self._const_cache[key] = _Constants(
                self.T_world_base.to(device=device, dtype=dtype),
                [s.T_parent_joint.to(device=device, dtype=dtype) for s in self._steps],
                [None if K is None else K.to(device=device, dtype=dtype) for K in self._K],
                [None if K is None else (K @ K).to(device=device, dtype=dtype) for K in self._K],
            )
        return self._const_cache[key]

    def link_transforms(self, q: torch.Tensor) -> dict[str, torch.Tensor]:
        """``T_world_link`` (B, 4, 4) for every link, from joint angles ``q`` (B, dof) [rad]."""
        batch = q.shape[0]
        c = self._constants(q.dtype, q.device)
        T = c.T_world_base.expand(batch, 4, 4)
        out = {self.root_link: T}
        eye = torch.eye(3, dtype=q.dtype, device=q.device)
        for step, T_pj, K, K2 in zip(self._steps, c.T_parent_joint, c.K, c.K2, strict=True):
            T = T @ T_pj
            if K is not None and K2 is not None:
                th = q[:, step.q_index].reshape(batch, 1, 1)
                R = eye + torch.sin(th) * K + (1.0 - torch.cos(th)) * K2  # Rodrigues
                Tj = torch.zeros(batch, 4, 4, dtype=q.dtype, device=q.device)
                Tj[:, :3, :3] = R
                Tj[:, 3, 3] = 1.0
                T = T @ Tj
            out[step.link] = T
        return out

    def link_positions(self, q: torch.Tensor, links: tuple[str, ...] | None = None) -> torch.Tensor:
        """Link-frame origins in the world frame (B, L, 3) for ``links`` (default: all)."""
        tf = self.link_transforms(q)
        names = links if links is not None else self.link_names
        return torch.stack([tf[n][:, :3, 3] for n in names], dim=1)

    def points_world(self, q: torch.Tensor, points: list[tuple[str, np.ndarray]]) -> torch.Tensor:
        """World positions (B, P, 3) of points given as (link name, xyz in that link frame)."""
        tf = self.link_transforms(q)
        cols = []
        for link, p in points:
            T = tf[link]
            pt = torch.as_tensor(p, dtype=q.dtype, device=q.device)
            cols.append(T[:, :3, :3] @ pt + T[:, :3, 3])
        return torch.stack(cols, dim=1)
