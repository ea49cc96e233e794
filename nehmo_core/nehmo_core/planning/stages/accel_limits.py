"""Commands the arm can follow: each joint's command changes by at most what its acceleration
limit reaches in one tick.

A row provider and a command filter (settings group ``actuator``; off by default and in the
``paper`` preset). The paper's Opt assumes ``q̇ = u``: any command within ū takes effect at once,
so its fail-safe flips every joint at full speed in one tick (a 1 rad/s step at ū = 0.5). A
real joint follows a velocity command at most as fast as its acceleration limit ``a_j``
(``facts.accel_limits`` of the robot's description) allows: a command it cannot reach is a plan
it does not follow.

The rows keep Opt's step ``y`` (held ``t_plan``) within
``t_plan·(u_prev_j ± share·a_j·tick)``, where ``u_prev`` is this planner's last command; the
fail-safe and an unconstrained step are projected onto them like every row provider's rows, so
the fail-safe becomes the best reachable command toward its direction. The filter clips the
final command to the same band (after the other filters, which may have shortened it) and
remembers it. The V rows against every peer's worst case stay; a step the band excludes makes
Opt infeasible, and then the fail-safe runs. It is built only for arms whose description gives
acceleration limits.

An arm that cannot stop at once must not close on a peer faster than it can brake before the
margin. With ``approach_rate`` γ the stage adds one row per peer, linear in the step:
``∇_{q_own}V·y ≥ −γ·t_plan·max(V − margin, 0)``: V may fall at most γ times its gap per second,
so the arm slows down as the gap closes (γ·(braking time) below one keeps the approach from
overshooting). A step of zero keeps the rows.

Near contact the learned V errs by centimetres, and an arm moving fast still travels
``u·|u|/(2a)`` per joint while it brakes. With ``brake_clearance`` the filter checks, with the
real geometry (the cell's shared PyBullet world), where the arm comes to rest if it sends the
command for one tick and then brakes at its limits, against every peer whose V reads below
``brake_near`` (posed where they are now). If that rest pose comes closer to a peer than
``brake_clearance`` (and than now, where the arms are already closer), the arm brakes as hard as
it can instead. In the slow game (the peer holds, i.e. announced a bound below full speed, this
arm announces a hold too and its command keeps within the hold's speed) the clearance is at most
``contact.holding_clearance``, as in the contact guard: with 4 cm, arms stopped short of goals
that lie beside a settled peer. At any higher speed it stays ``brake_clearance``.

The band can also make Opt infeasible with no peer near: an arm moving fast beside its own links
cannot turn as fast as the self-clearance rows ask. The paper's fail-safe then drives it at full
speed up the gradient of a peer's V that is nowhere near its margin, sometimes into the same
conflict a few ticks later (an arm looped so for 20 s, dual UR5, seed 67, scenario 65). With
``far_brake`` (off by default), a fail-safe with every peer's V at least ``brake_near`` brakes as
hard as it can instead; it ends that loop but cost the UR5-Kinova cell five points of success
(seed 67: 85 against 90 %), so it is not part of the ``real_actuators`` preset.
"""

from __future__ import annotations

import numpy as np

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.opt.peer_bounds import FULL_SPEED
from nehmo_core.planning.opt.pipeline import Host, margin_gaps
from nehmo_core.planning.opt.problem import LinearRows
from nehmo_core.planning.opt.tick import PeerValues, Tick
from nehmo_core.planning.stages.exact_guard import WorldFilter, distances

__all__ = ["AccelLimits"]


class AccelLimits(WorldFilter):
    """The ``actuator`` row provider and command filter of one planner."""

    name = "actuator"

    def __init__(self, host: Host) -> None:
        s = host.settings
        limits = host.robot.facts.accel_limits
        if limits is None:
            rule = f"needs facts.accel_limits in the description of robot {host.robot.name!r}"
            raise InvalidValueError("actuator.enabled", rule, True)
        super().__init__(host, world=s.actuator.brake_clearance > 0.0)
        self.dof = host.robot.dof
        self.rate = s.actuator.approach_rate
        self.t_plan = s.opt.t_plan
        # [rad/s] the change of command one tick reaches, per joint
        self.accel = s.actuator.share * np.asarray(limits, dtype=float)
        self.reach = s.opt.tick * self.accel
        self.braked = 0
        self.reset()

    def reset(self) -> None:
        """At rest: the last command is zero."""
        self.last = np.zeros(self.dof)
        self.shortened = 0
        self.braked = 0

    def rows(self, q: np.ndarray) -> LinearRows:
        """``y_j ≥ t_plan·(last_j − reach_j)`` and ``−y_j ≥ −t_plan·(last_j + reach_j)``."""
        eye = np.eye(self.dof)
        low, high = self._band()
        return LinearRows(np.vstack([eye, -eye]), np.concatenate([low, -high]) * self.t_plan)

    def peer_rows(self, tick: Tick, now: PeerValues) -> LinearRows | None:
        """``∇_{q_own}V_i·y ≥ −γ·t_plan·max(V_i − margin_i, 0)`` for each peer ``i``."""
        if not now.ids:
            return None
        grads = np.array([g[: self.dof] for g in now.grads])
        gaps = np.maximum(margin_gaps(self.host, now), 0.0)
        return LinearRows(grads, -self.rate * self.t_plan * gaps)

    def filter(self, tick: Tick, now: PeerValues, u: np.ndarray) -> np.ndarray:
        """``u`` clipped to the commands reachable from the last one; remembered as the last."""
        if (
            tick.fail_safe
            and self.host.settings.actuator.far_brake
            and now.ids
            and float(now.values.min()) >= self.host.settings.actuator.brake_near
        ):
            # Opt failed on the linear rows (this band against the self-clearance rows), not
            # on a peer: the fail-safe's full-speed step away from a far peer would only drive
            # the arm on; it brakes instead
            self.braked += 1
            self.last = self._hardest_braking()
            return self.last
        out = np.clip(u, *self._band())
        self.shortened += not np.array_equal(out, u)
        out = self._brake(tick, now, out)
        self.last = np.array(out, dtype=float)
        return out

    def _rest(self, q: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Where the arm stops if it sends ``u`` for a tick and then brakes at its limits."""
        return q + u * self.host.settings.opt.tick + u * np.abs(u) / (2.0 * self.accel)

    def _brake(self, tick: Tick, now: PeerValues, u: np.ndarray) -> np.ndarray:
        """``u`` if its rest pose keeps each near peer's braking clearance (or, already closer
        to that peer, comes no closer to it); else the hardest braking the band allows."""
        s = self.host.settings.actuator
        if self._lease is None:
            return u
        near = {
            p: tick.peers[p] for p, v in zip(now.ids, now.values, strict=True) if v < s.brake_near
        }
        if not near:
            return u
        world, arm, peers = self._lease.world, self.host.arm_id, list(near)
        world.set_configuration(near)
        clearance = self._clearances(tick, peers, u)
        cutoff = float(clearance.max()) + 0.05
        rest = distances(world, arm, self._rest(tick.q, u), peers, cutoff)
        inside = rest < clearance
        if not inside.any():
            return u
        # the distance now matters only to the peers the rest pose comes within clearance of
        closer = [p for p, hit in zip(peers, inside, strict=True) if hit]
        if (rest[inside] >= distances(world, arm, tick.q, closer, cutoff)).all():
            return u
        self.braked += 1
        return self._hardest_braking()

    def _clearances(self, tick: Tick, peers: list[str], u: np.ndarray) -> np.ndarray:
        """The braking clearance [m] against each of ``peers``. In the slow game (the peer
        holds, this arm announces a hold too and ``u`` keeps within the hold's speed) at most
        the contact guard's ``holding_clearance``: with 4 cm, five UR5s stopped 0.03-0.06 rad
        short of goals beside a settled peer. An arm moving faster keeps ``brake_clearance``:
        at full speed, a Kinova that braked only 1 cm before a holding UR5 reached its base
        (latency and the acceleration band carried it the last centimetre)."""
        s = self.host.settings
        full = s.actuator.brake_clearance
        hold_speed = s.hold.bound * s.opt.u_max * (1.0 + 1e-9)  # [rad/s]
        slow = tick.announced < FULL_SPEED and float(np.abs(u).max()) <= hold_speed
        held = min(full, s.contact.holding_clearance) if slow else full
        return np.array([held if tick.holds(p) else full for p in peers])

    def _band(self) -> tuple[np.ndarray, np.ndarray]:
        """The lowest and highest command [rad/s] each joint reaches from the last in a tick."""
        return self.last - self.reach, self.last + self.reach

    def _hardest_braking(self) -> np.ndarray:
        """The command in the band nearest to standing still."""
        return np.clip(np.zeros(self.dof), *self._band())
