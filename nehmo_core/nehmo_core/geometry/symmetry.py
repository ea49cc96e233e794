"""Mirror symmetry of an arm pair, as joint maps ``q → sign·q + offset`` (wrapped).

A pair cell whose two bases lie in the world's x-z plane, each facing along ±x, is symmetric
under the mirror ``y → −y``. For each robot there is a joint map that sends a configuration to
its mirror image; it depends on the URDF's joint zeros, so it is found here by search (the
per-joint candidates ``±q + {0, ±π/2, π}``, chosen joint by joint so that every link-frame
origin lands on the mirror of its old position) and verified in the tests on the exact geometry.
Applied to both arms, the map leaves the pair's signed distance unchanged, and so the HJR value
function (paper Appendix; the map never touches time).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import torch

from nehmo_core.errors import NehmoError
from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import RobotModel, wrap_angle

_MIRROR_Y = np.diag([1.0, -1.0, 1.0])
_OFFSETS = (0.0, np.pi / 2, -np.pi / 2, np.pi)


@dataclass(frozen=True)
class JointMap:
    """``q → sign·q + offset`` per joint; periodic joints are wrapped to (−π, π]."""

    sign: tuple[float, ...]
    offset: tuple[float, ...]
    periodic: tuple[bool, ...]

    def apply(self, q: np.ndarray) -> np.ndarray:
        out = np.asarray(q, dtype=np.float64) * np.array(self.sign) + np.array(self.offset)
        per = np.array(self.periodic)
        out[..., per] = wrap_angle(out[..., per])
        return out

    def apply_torch(self, q: torch.Tensor) -> torch.Tensor:
        sign = torch.tensor(self.sign, dtype=q.dtype)
        off = torch.tensor(self.offset, dtype=q.dtype)
        out = q * sign + off
        per = torch.tensor(self.periodic)
        wrapped = torch.remainder(out + torch.pi, 2 * torch.pi) - torch.pi
        return torch.where(per, wrapped, out)

    def __add__(self, other: JointMap) -> JointMap:
        """Concatenate two maps (arm 1's, then arm 2's)."""
        return JointMap(
            self.sign + other.sign, self.offset + other.offset, self.periodic + other.periodic
        )


def _origins(kin: ArmKinematics, q: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return kin.link_positions(torch.from_numpy(q)).numpy()  # (B, L, 3)


def _dependencies(kin: ArmKinematics, q: np.ndarray) -> np.ndarray:
    """(dof, L) mask: whether link origin l moves when joint j moves."""
    base = _origins(kin, q)
    deps = []
    for j in range(q.shape[1]):
        dq = q.copy()
        dq[:, j] += 0.3
        deps.append(np.abs(_origins(kin, dq) - base).max(axis=(0, 2)) > 1e-9)
    return np.array(deps)


def find_mirror_map(robot: RobotModel, samples: int = 64) -> JointMap:
    """Search the joint map that mirrors the arm across its base's x-z plane.

    A joint whose motion moves no link-frame origin (a last joint turning about the flange
    axis) is left as ``q → −q``: origins cannot tell its map apart, and the collision shape
    it turns is round about that axis.
    """
    kin = ArmKinematics(robot)
    rng = np.random.default_rng(0)
    lo = np.maximum(robot.lower, -np.pi)
    hi = np.minimum(robot.upper, np.pi)
    q = rng.uniform(lo, hi, size=(samples, robot.dof))
    target = _origins(kin, q) @ _MIRROR_Y
    deps = _dependencies(kin, q)
    sign: list[float] = []
    offset: list[float] = []
    for j in range(robot.dof):
        # Links moved by joint j and by no later joint.
        links = deps[j] & ~deps[j + 1 :].any(axis=0)
        if not links.any():
            sign.append(-1.0)
            offset.append(0.0)
            continue
        best: tuple[float, float, float] | None = None
        for s in (-1.0, 1.0):
            for c in _OFFSETS:
                trial = q.copy()
                trial[:, :j] = np.array(sign) * q[:, :j] + np.array(offset)
                trial[:, j] = s * q[:, j] + c
                err = float(np.abs(_origins(kin, trial)[:, links] - target[:, links]).max())
                if best is None or err < best[0]:
                    best = (err, s, c)
        assert best is not None
        if best[0] > 1e-6:
            raise NehmoError(
                f"no mirror map for joint {robot.joint_names[j]} (error {best[0]:.3g})"
            )
        sign.append(best[1])
        offset.append(best[2])
    return JointMap(tuple(sign), tuple(offset), tuple(bool(c) for c in robot.continuous))


@functools.cache
def robot_mirror_map(robot_name: str) -> JointMap:
    """The mirror joint map of a shipped robot (cached)."""
    return find_mirror_map(load_robot(robot_name))
