"""The contact guard of a NeHMO arm: with the real geometry, never step closer to a peer
that is already within a few centimetres, and step away from it when the fail-safe would not.

A command filter stage (settings group ``contact``; ``clearance`` 0, the ``paper`` preset, turns
it off). It may shorten a command, or replace a command that would close a near-contact gap by
one up the real distance's gradient; the V rows against every peer's worst case stay (they
shaped the command it starts from, and it acts only within ``clearance + approach`` of contact,
inside every margin ε the rows keep).

Why: the guarantee of the V rows holds from states where V ≥ ε. An episode can start inside
that margin (the scenario protocol only asks for collision-free starts; starts 1 mm apart
occur), and there the learned V, which errs by centimetres near contact, can point the
fail-safe's full-speed step ``ū·sign(∂V/∂q)`` into the peer. With three or more arms inside
one another's margins the paper's fail-safe, which looks only at the most critical peer, can
also step into another one.

The guard checks, with PyBullet, every peer whose V reads below ``contact.value``, each on its
own: a peer closer than its clearance plus ``contact.approach`` is watched, and the step (end
and midpoint, the peers posed where they are now) may bring no watched peer closer than it is
now, nor within its clearance. The clearance is ``contact.clearance``, or
``contact.holding_clearance`` (the smaller) against a peer that holds: one that announced a
bound below full speed moves at most ``hold.bound·d̄`` and cannot close a gap as two arms at
full speed do. A step that would is shortened (``contact.scales``: ½,
¼); if none fits it is replaced by ``cap·ū·g/max|g|`` along the gradient ``g`` of the real
distance to the nearest watched peer over this arm's joints (central differences of
``contact.probe`` rad), else along the sum of the watched peers' unit gradients, kept within
the row providers' rows and checked the same way (otherwise the arm stays still). Two arms that
each do this do not close their gap to first order, however many peers each has near.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.planning.opt.pipeline import Host
from nehmo_core.planning.opt.problem import project_step
from nehmo_core.planning.opt.tick import PeerValues, Tick
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.stages.exact_guard import WorldFilter, distances

__all__ = ["ContactGuard", "contact_step"]


def _fits(
    world: CellWorld,
    arm_id: str,
    q: np.ndarray,
    step: np.ndarray,
    peers: list[str],
    floors: np.ndarray,
    scales: tuple[float, ...],
) -> float:
    """The first share of ``step`` [rad] in ``scales`` whose end and midpoint keep every peer
    of ``peers`` at least its floor away (0 if none)."""
    cutoff = float(floors.max()) + 0.05
    for scale in scales:
        ends = [distances(world, arm_id, q + f * scale * step, peers, cutoff) for f in (1.0, 0.5)]
        if all(bool((d >= floors).all()) for d in ends):
            return scale
    return 0.0


def _gradient(
    world: CellWorld, arm_id: str, q: np.ndarray, peer: str, now: float, probe: float
) -> np.ndarray:
    """The real distance to ``peer`` differentiated over this arm's joints [m/rad]."""
    grad = np.zeros(len(q))
    cutoff = now + 2 * probe + 0.05
    for j in range(len(q)):
        dq = np.zeros(len(q))
        dq[j] = probe
        hi = distances(world, arm_id, q + dq, [peer], cutoff)[0]
        lo = distances(world, arm_id, q - dq, [peer], cutoff)[0]
        grad[j] = (hi - lo) / (2 * probe)
    return grad


def _clearance(s: PlannerSettings, tick: Tick, peer: str) -> float:
    """The real distance [m] below which no step may close on ``peer``."""
    if tick.holds(peer):
        return min(s.contact.clearance, s.contact.holding_clearance)
    return s.contact.clearance


def contact_step(
    world: CellWorld, host: Host, tick: Tick, u: np.ndarray, near: Mapping[str, np.ndarray]
) -> tuple[np.ndarray, bool]:
    """The command [rad/s] to send instead of ``u`` against the peers ``near`` (``{peer: q}``)
    and whether it differs from ``u``."""
    s, arm_id, q = host.settings, host.arm_id, tick.q
    world.set_configuration(near)
    # a peer that holds (announced a bound below full speed) closes the gap slower: it keeps
    # ``holding_clearance``
    clearance = np.array([_clearance(s, tick, p) for p in near])
    watch = clearance + s.contact.approach
    now = distances(world, arm_id, q, list(near), float(watch.max()) + 0.01)
    inside = now < watch
    if not inside.any():
        return u, False
    # each watched peer on its own: a step may not end (or pass) closer to it than it is now,
    # nor within its clearance (a step that eased the nearest peer while closing on the
    # next let three arms in one another's margins touch)
    peers = [p for p, watched in zip(near, inside, strict=True) if watched]
    gaps = now[inside]
    floors = np.minimum(gaps, clearance[inside])
    t = s.opt.t_plan
    share = _fits(world, arm_id, q, u * t, peers, floors, s.contact.scales)
    if share >= 1.0:
        return u, False
    if share > 0.0:
        return u * share, True
    y_max = t * s.opt.u_max * tick.cap
    order = np.argsort(gaps)
    grads = [_gradient(world, arm_id, q, peers[i], float(gaps[i]), s.contact.probe) for i in order]
    # up the nearest peer's real distance, else up every watched peer's at once
    units = [g / n for g in grads if (n := float(np.linalg.norm(g))) > 1e-9]
    candidates = [grads[0], np.sum(units, axis=0)] if len(units) > 1 else [grads[0]]
    for grad in candidates:
        if float(np.abs(grad).max()) < 1e-6:
            continue
        step = y_max * grad / float(np.abs(grad).max())
        if tick.rows is not None and tick.rows.count:
            step = project_step(step, tick.rows, y_max)
        share = _fits(world, arm_id, q, step, peers, floors, s.contact.scales)
        if share > 0.0:
            return step * share / t, True
    return np.zeros_like(u), True


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
