"""The set-up of :class:`~nehmo_core.planning.stages.self_clearance.SelfClearance` (``sc``,
passed in: this module does not import it) for a robot:
per link pair a bound on how fast joint motion can change its distance (queries are skipped
while the bound says the pair cannot have come within reach), and the order in which PyBullet
reports the pair's witness points (found once per robot).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pybullet as pb

__all__ = ["distance_slopes", "witness_order"]


def distance_slopes(sc: Any, parent: dict[int, int]) -> np.ndarray:
    """(pairs, dof): per link pair and joint, a bound [m/rad] on ``|∂d/∂q_j|`` over every
    configuration, so that ``|d(q) − d(q')| ≤ Σ_j bound_j·|q_j − q'_j|``.

    A joint that moves both links (or neither) leaves their distance alone. One that moves
    only link ``a`` moves a point of it at most as fast as the point's distance from the
    joint's origin: at most the chain of link-frame offsets from the joint to ``a`` (each is
    fixed in its parent link) plus ``a``'s reach from its own frame, read from its
    axis-aligned box at one configuration (the box holds the geometry, so the reach is not
    underestimated). A prismatic joint moves any point at 1 m/m."""
    client, body, ours = sc._client, sc._body, sc._joints
    links = range(pb.getNumJoints(body, physicsClientId=client))
    q0 = np.clip(np.zeros(sc.robot.dof), sc.robot.lower, sc.robot.upper)
    sc._world.set_joint_positions("self", q0)
    frames = {
        k: np.array(st[4])
        for k, st in zip(
            links,
            pb.getLinkStates(body, list(links), True, physicsClientId=client),
            strict=True,
        )
    }

    def reach(joint: int, link: int) -> float:
        lo, hi = (np.array(v) for v in pb.getAABB(body, link, physicsClientId=client))
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        out, k = float(np.linalg.norm(corners - frames[link], axis=1).max()), link
        while k != joint:
            out += float(np.linalg.norm(frames[k] - frames[parent[k]]))
            k = parent[k]
        return out

    slope = np.zeros((len(sc._pairs), len(ours)))
    for p, (_, _, la, lb) in enumerate(sc._pairs):
        for k, j in enumerate(ours):
            a, b = sc._moves[la][k], sc._moves[lb][k]
            if a == b:
                continue
            slope[p, k] = 1.0 if sc._prismatic[k] else reach(j, la if a else lb)
    return slope


def witness_order(sc: Any, samples: int = 60, seed: int = 0) -> dict[tuple[str, str], bool]:
    """Per link pair: whether PyBullet reports its witness points in swapped order.

    For some shape combinations (e.g. a mesh against a compound shape) the query returns
    the point on link B as "position on A" (the normal still points from the second point
    to the first). The order is fixed per pair, so it is found once: on random
    configurations, the gradient from the assumed order must predict the change of the
    distance along itself; a majority vote per pair decides.
    """
    rng = np.random.default_rng(seed)
    votes = {pair: 0 for pair in sc._swapped}
    lo = np.maximum(sc.robot.lower, -np.pi)
    hi = np.minimum(sc.robot.upper, np.pi)
    for _ in range(samples):
        q = rng.uniform(lo, hi)
        rows = sc.rows(q)
        for grad, d, pair in zip(rows.A, rows.distances, rows.pairs, strict=True):
            norm = float(np.linalg.norm(grad))
            if d < 0.005 or norm < 1e-3:
                continue
            dq = 1e-3 * grad / norm
            ahead = sc.distances(q + dq).get(pair)
            behind = sc.distances(q - dq).get(pair)
            if ahead is None or behind is None:
                continue
            change, predicted = (ahead - behind) / 2.0, float(grad @ dq)
            votes[pair] += 1 if change * predicted > 0 else -1
    return {pair: vote < 0 for pair, vote in votes.items()}
