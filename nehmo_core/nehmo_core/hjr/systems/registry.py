"""The system registry: names accepted by ``make_system`` and ``nehmo train --system``.

Every system is listed here explicitly, the arm pairs as the robot registry
(:mod:`nehmo_core.robots.registry`) names them; they are built by
:func:`.arm_pairs.make_arm_pair_system`, imported when one is made (it loads the learned
distance models). :func:`register_system` adds a system (e.g. in a test or a script).
"""

from __future__ import annotations

from collections.abc import Callable

from nehmo_core.errors import UnknownNameError
from nehmo_core.hjr.systems.air3d import Air3D
from nehmo_core.hjr.systems.base import HJISystem
from nehmo_core.hjr.systems.two_link import TwoLinkPair
from nehmo_core.robots.registry import PAIR_NAMES

__all__ = ["make_system", "register_system", "system_names"]

ARM_PAIR_NAMES = PAIR_NAMES
"""The arm pairs built by :func:`.arm_pairs.make_arm_pair_system`: every pair of the robot
registry (:data:`~nehmo_core.robots.registry.ARM_PAIRS`; ``*_any``: conditioned on the base
distance, for any layout). Building one loads its learned distance, which for
``ur5_kinova_any`` / ``kinova_ur5_any`` must be trained first (``nehmo distance train --pair
ur5_kinova_any``): until then they raise :class:`~nehmo_core.errors.ModelFileError`."""


def _arm_pair_factory(pair: str) -> Callable[[], HJISystem]:
    def build() -> HJISystem:
        from nehmo_core.hjr.systems.arm_pairs import make_arm_pair_system

        return make_arm_pair_system(pair)

    return build


_REGISTRY: dict[str, Callable[[], HJISystem]] = {
    "air3d": Air3D,
    "two_link": TwoLinkPair,
    **{pair: _arm_pair_factory(pair) for pair in ARM_PAIR_NAMES},
}


def register_system(name: str, factory: Callable[[], HJISystem]) -> None:
    """Make ``make_system(name)`` build systems with ``factory``."""
    _REGISTRY[name] = factory


def system_names() -> list[str]:
    """Names accepted by :func:`make_system`."""
    return sorted(_REGISTRY)


def make_system(name: str) -> HJISystem:
    """Build a registered system by name; unknown names raise :class:`UnknownNameError`."""
    if name not in _REGISTRY:
        raise UnknownNameError("system", name, _REGISTRY)
    return _REGISTRY[name]()
