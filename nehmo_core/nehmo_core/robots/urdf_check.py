"""Is this URDF an arm NeHMO can plan for? The checks ``nehmo robot check`` runs.

An arm is a serial chain of revolute or continuous joints from the URDF's root link to a tip
link; every joint states its limits and its velocity bound (the planner's ``ū`` comes from
it), and every link the joints move carries collision geometry, since distances, value
functions and the simulator all work on the collision shapes. Branches off the chain (a
gripper's fingers) are reported and ignored. ``package://NAME/...`` mesh URIs are resolved
against the folders above the URDF and the ``example-robot-data`` package; a mesh that cannot
be found is an error.

Every failed check raises :class:`~nehmo_core.errors.ModelFileError` naming the file, the
element and what is missing or wrong.
"""

from __future__ import annotations

import contextlib
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from nehmo_core.errors import ModelFileError
from nehmo_core.robots.descriptions import example_robot_data_share

__all__ = ["ChainJoint", "UrdfReport", "check_urdf", "mesh_path", "package_roots"]

MOVABLE = ("revolute", "continuous")


@dataclass(frozen=True)
class ChainJoint:
    """One joint of the chain: name, kind, limits [rad] and velocity bound [rad/s]."""

    name: str
    kind: str
    lower: float
    upper: float
    velocity: float


@dataclass(frozen=True)
class UrdfReport:
    """What the check found: the chain root → tip, its joints and what is ignored."""

    urdf: Path
    robot: str
    root: str
    tip: str
    joints: tuple[ChainJoint, ...]
    collision_links: tuple[str, ...]
    ignored_links: tuple[str, ...]

    @property
    def dof(self) -> int:
        return len(self.joints)

    def summary(self) -> str:
        lines = [
            f"{self.urdf}: robot {self.robot!r}, {self.dof} joints from {self.root} to {self.tip}"
        ]
        for j in self.joints:
            limits = "continuous" if j.kind == "continuous" else f"[{j.lower:.3f}, {j.upper:.3f}]"
            lines.append(f"  {j.name}: {limits} rad, at most {j.velocity:g} rad/s")
        lines.append(f"  collision geometry on: {', '.join(self.collision_links)}")
        if self.ignored_links:
            lines.append(f"  off the chain (ignored): {', '.join(self.ignored_links)}")
        return "\n".join(lines)


def _fail(urdf: Path, what: str) -> ModelFileError:
    return ModelFileError(f"{urdf}: {what}")


def package_roots(urdf: Path) -> list[Path]:
    """Folders a ``package://NAME/`` URI may be relative to: every folder above the URDF, and
    the ``example-robot-data`` share folder when that package is installed."""
    roots = list(urdf.resolve().parents)
    with contextlib.suppress(ModelFileError):  # not installed: the folders above the URDF
        roots.append(example_robot_data_share().parent)
    return roots


def mesh_path(urdf: Path, uri: str, roots: list[Path]) -> Path | None:
    if uri.startswith("package://"):
        rel = uri[len("package://") :]
        for root in roots:
            if (root / rel).exists():
                return root / rel
        return None
    if uri.startswith("file://"):
        uri = uri[len("file://") :]
    path = Path(uri) if Path(uri).is_absolute() else urdf.parent / uri
    return path if path.exists() else None


def _joint_of(urdf: Path, j: ET.Element) -> ChainJoint:
    name, kind = j.attrib.get("name", "?"), j.attrib.get("type", "?")
    if kind not in MOVABLE:
        raise _fail(
            urdf,
            f"joint {name!r} is {kind}: the chain may hold only revolute and continuous joints "
            "(and fixed ones)",
        )
    lim = j.find("limit")
    attrs = lim.attrib if lim is not None else {}
    if "velocity" not in attrs:
        raise _fail(urdf, f"joint {name!r} has no <limit velocity=...> (its speed bound [rad/s])")
    velocity = float(attrs["velocity"])
    if not (math.isfinite(velocity) and velocity > 0):
        raise _fail(urdf, f"joint {name!r}: limit velocity must be > 0 rad/s; got {velocity}")
    if kind == "continuous":
        return ChainJoint(name, kind, -math.inf, math.inf, velocity)
    if "lower" not in attrs or "upper" not in attrs:
        raise _fail(urdf, f"revolute joint {name!r} has no <limit lower=... upper=...>")
    lower, upper = float(attrs["lower"]), float(attrs["upper"])
    if not lower < upper:
        raise _fail(urdf, f"joint {name!r}: limit lower ({lower}) must be < upper ({upper})")
    return ChainJoint(name, kind, lower, upper, velocity)


def check_urdf(urdf: Path, tip: str | None = None) -> UrdfReport:
    """Check ``urdf`` as an arm from its root link to ``tip`` (default: the one leaf that the
    most movable joints lead to, when that leaf is unique)."""
    if not urdf.is_file():
        raise ModelFileError(f"URDF not found: {urdf}")
    try:
        robot = ET.parse(urdf).getroot()
    except ET.ParseError as exc:
        raise _fail(urdf, f"not valid XML ({exc})") from exc
    if robot.tag != "robot":
        raise _fail(urdf, f"the root element is <{robot.tag}>, not <robot>")
    links = {lk.attrib.get("name", "?"): lk for lk in robot.findall("link")}
    parent_of: dict[str, ET.Element] = {}
    for j in robot.findall("joint"):
        parent, child = j.find("parent"), j.find("child")
        if parent is None or child is None:
            raise _fail(urdf, f"joint {j.attrib.get('name', '?')!r} lacks <parent> or <child>")
        for end in (parent.attrib.get("link", ""), child.attrib.get("link", "")):
            if end not in links:
                raise _fail(urdf, f"joint {j.attrib.get('name')!r} names unknown link {end!r}")
        c = child.attrib["link"]
        if c in parent_of:
            raise _fail(urdf, f"link {c!r} is the child of two joints: not a tree")
        parent_of[c] = j
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        raise _fail(urdf, f"needs one root link (a link no joint moves); found {roots}")

    def chain(link: str) -> list[ET.Element]:
        out = []
        while link in parent_of:
            out.append(parent_of[link])
            link = parent_of[link].find("parent").attrib["link"]  # type: ignore[union-attr]
        return out[::-1]

    def movable(joints: list[ET.Element]) -> int:
        return sum(j.attrib.get("type") != "fixed" for j in joints)

    if tip is None:
        parents = {j.find("parent").attrib["link"] for j in parent_of.values()}  # type: ignore[union-attr]
        leaves = sorted((movable(chain(lk)), lk) for lk in links if lk not in parents)
        best = [lk for n, lk in leaves if n == leaves[-1][0]]
        if len(best) != 1:
            listed = ", ".join(f"{lk} ({n} movable joints)" for n, lk in leaves if n)
            raise _fail(urdf, f"several chains could be the arm: {listed}; name the tip link")
        tip = best[0]
    if tip not in links:
        raise _fail(urdf, f"tip link {tip!r} is not in the URDF (links: {sorted(links)})")
    path = chain(tip)
    joints = tuple(_joint_of(urdf, j) for j in path if j.attrib.get("type") != "fixed")
    if not joints:
        raise _fail(urdf, f"no movable joint leads from the root to {tip!r}")
    on_chain = [path[0].find("parent").attrib["link"]] + [  # type: ignore[union-attr]
        j.find("child").attrib["link"]  # type: ignore[union-attr]
        for j in path
    ]
    with_collision = [lk for lk in on_chain if links[lk].find("collision") is not None]
    # the links each movable joint moves rigidly (up to the next movable joint) must carry
    # collision geometry somewhere
    bodies: list[tuple[str, list[str]]] = []
    for j in path:
        moved = j.find("child").attrib["link"]  # type: ignore[union-attr]
        if j.attrib.get("type") != "fixed":
            bodies.append((j.attrib.get("name", "?"), [moved]))
        elif bodies:
            bodies[-1][1].append(moved)
    for mover, body in bodies:
        if not any(lk in with_collision for lk in body):
            raise _fail(
                urdf,
                f"links {body} moved by joint {mover!r} have no <collision> geometry "
                "(distances and collisions use the collision shapes)",
            )
    search = package_roots(urdf)
    for lk in with_collision:
        for mesh in (m for c in links[lk].findall("collision") for m in c.iter("mesh")):
            uri = mesh.attrib.get("filename", "")
            if mesh_path(urdf, uri, search) is None:
                raise _fail(urdf, f"collision mesh of link {lk!r} not found: {uri!r}")
    ignored = tuple(sorted(set(links) - set(on_chain)))
    return UrdfReport(
        urdf,
        robot.attrib.get("name", urdf.stem),
        on_chain[0],
        tip,
        joints,
        tuple(with_collision),
        ignored,
    )
