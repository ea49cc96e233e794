"""The contact guard of a NeHMO arm: with the real geometry, never step closer to a peer
that is already within a few centimetres, and step away from it when the fail-safe would not.

A command filter stage (settings group ``contact``; ``clearance`` 0, the ``paper`` preset, turns
it off). It may shorten a command, or replace a command that would close a near-contact gap by
one up the real distance's gradient; the V rows against every peer's worst case stay (they
shaped the command it starts from, and it acts only within ``clearance`` of contact, inside
every margin ε the rows keep).

Why: the guarantee of the V rows holds from states where V ≥ ε. An episode can start inside
that margin (the scenario protocol only asks for collision-free starts; starts 1 mm apart
occur), and there the learned V, which errs by centimetres near contact, can point the
fail-safe's full-speed step ``ū·sign(∂V/∂q)`` into the peer. The guard checks, with PyBullet,
every peer whose V reads below ``contact.value``: when the arms are closer than
``contact.clearance`` the step (end and midpoint, the peers posed where they are now) may not
bring them closer; a step that would is shortened (``contact.scales``: ½, ¼), and if none
fits it is replaced by ``cap·ū·g/max|g|`` along the gradient ``g`` of the real distance over
this arm's joints (central differences of ``contact.probe`` rad), kept within the row
providers' rows and checked the same way (otherwise the arm stays still). Two arms that each
do this do not close their gap to first order.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.planning.opt.pipeline import Host
from nehmo_core.planning.opt.problem import project_step
from nehmo_core.planning.opt.tick import PeerValues, Tick
from nehmo_core.planning.stages.exact_guard import WorldFilter, closest

__all__ = ["ContactGuard", "contact_step"]


def _fits(
    world: CellWorld,
    arm_id: str,
    q: np.ndarray,
    step: np.ndarray,
    peers: list[str],
    now: float,
    scales: tuple[float, ...],
) -> float:
    """The first share of ``step`` [rad] in ``scales`` whose end and midpoint are no closer
    than ``now`` (0 if none)."""
    cutoff = now + 0.05
    for scale in scales:
        ends = [closest(world, arm_id, q + f * scale * step, peers, cutoff) for f in (1.0, 0.5)]
        if min(ends) >= now:
            return scale
    return 0.0


def contact_step(
    world: CellWorld, host: Host, tick: Tick, u: np.ndarray, near: Mapping[str, np.ndarray]
) -> tuple[np.ndarray, bool]:
    """The command [rad/s] to send instead of ``u`` against the peers ``near`` (``{peer: q}``)
    and whether it differs from ``u``."""
    s, arm_id, q = host.settings, host.arm_id, tick.q
    world.set_configuration(near)
    peers = list(near)
    clearance = s.contact.clearance
    now = closest(world, arm_id, q, peers, clearance + 0.01)
    if now >= clearance:
        return u, False
    t = s.opt.t_plan
    share = _fits(world, arm_id, q, u * t, peers, now, s.contact.scales)
    if share >= 1.0:
        return u, False
    if share > 0.0:
        return u * share, True
    h = s.contact.probe
    grad = np.zeros(len(q))
    for j in range(len(q)):
        dq = np.zeros(len(q))
        dq[j] = h
        cutoff = now + 2 * h + 0.05
        hi = closest(world, arm_id, q + dq, peers, cutoff)
        lo = closest(world, arm_id, q - dq, peers, cutoff)
        grad[j] = (hi - lo) / (2 * h)
    peak = float(np.abs(grad).max())
    if peak < 1e-6:
        return np.zeros_like(u), True
    y_max = t * s.opt.u_max * tick.cap
    step = y_max * grad / peak
    if tick.rows is not None and tick.rows.count:
        step = project_step(step, tick.rows, y_max)
    share = _fits(world, arm_id, q, step, peers, now, s.contact.scales)
    return step * share / t, True


class ContactGuard(WorldFilter):
    """The ``contact`` command filter of one planner."""

    name = "contact"

    def filter(self, tick: Tick, now: PeerValues, u: np.ndarray) -> np.ndarray:
        """``u``, or the contact step against the peers whose V reads below
        ``contact.value``."""
        if self._lease is None:
            return u
        value = self.host.settings.contact.value
        near = {p: tick.peers[p] for p, v in zip(now.ids, now.values, strict=True) if v < value}
        if not near:
            return u
        out, changed = contact_step(self._lease.world, self.host, tick, u, near)
        self.shortened += changed
        return out
