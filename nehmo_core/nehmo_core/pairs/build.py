"""``nehmo pair build A B``: from two robot descriptions to a certified, pose-conditioned pair.

One command runs every stage of a pair's models, each a command a user could type, in a work
folder that remembers what is done (run it again and it goes on where it stopped):

1. ``check``: both robots load, have keypoints and a base-yaw first joint; the mirror map of
   each is found by search and verified on the exact geometry (the pair distance of mirrored
   states equals the original's); each arm's reach fixes the base distances that can touch
   (:mod:`.reach`). Writes the pair manifest (``<pair>.pairs.yaml``) into the model folder.
2. ``labels``: PyBullet distance labels (training, held-out and calibration sets, own seeds).
3. ``distance``: the learned distance on keypoints in the collision geometry (``distance train``).
4. ``calibrate``: kept unbiased (``nehmo distance calibrate --unbiased``): no offset.
5. ``distance-certificate``: the learned distance on exact contact states (α, β).
6. ``value:<game>``: the conditioned ``bc+sym`` value function of each side (one for a pair of
   the same robot; both games ``A_B_any`` and ``B_A_any`` otherwise), copied to the folder, and
   measured against its PDE; one that learned little is trained once more with the squared PDE
   residual (:mod:`.value_stage`), and a warning in the card if neither learned.
7. ``certify:<game>``: ``nehmo verify`` over uniform states at the planner's ``t_safe``.
8. ``falsify:<game>``: states the planner would call safe (``V(t_safe) ≥ ε``) rolled out against
   every adversary on the exact geometry: the contact rate and its bound.
9. ``visit``: the planner with these models on three two-arm cells of the pair (:mod:`.visit`).
10. ``certify-visited:<game>``: ``nehmo verify`` over the pair states of those episodes (the
    planner keeps the larger of the two levels in the model card).
11. ``card``: the pair card ``<pair>.card.json``: every command, seed, wall time and figure.

The model folder is where the pair's files go (``--models``, default the first folder of
``NEHMO_MODELS``); NeHMO finds the pair there when that folder is in ``NEHMO_MODELS``.
"""

from __future__ import annotations

import functools
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from nehmo_core.cluster import parse_cluster
from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.hjr.diagnostics import unlearned_warning
from nehmo_core.pairs import visit
from nehmo_core.pairs.budgets import BUDGETS
from nehmo_core.pairs.check import judge_mirror, pair_names, robot_figures, write_manifest
from nehmo_core.pairs.probes import RESULT
from nehmo_core.pairs.reach import checked_range
from nehmo_core.pairs.value_stage import value_stage
from nehmo_core.robots import registry
from nehmo_core.robots.descriptions import robot_names
from nehmo_core.robots.loader import atomic_write

__all__ = ["PairBuild", "pair_names"]


def default_models_dir() -> Path:
    """The first folder of ``NEHMO_MODELS``, else ``./nehmo_models``."""
    dirs = registry.model_dirs_env()
    return Path(dirs[0]) if dirs else Path("nehmo_models")


@dataclass
class StageRecord:
    """What a stage ran and measured; its wall time is set by :meth:`PairBuild.run`."""

    commands: list[str]
    figures: dict[str, Any]
    wall_time_s: float = 0.0


class PairBuild:
    """The build of one pair in ``work`` (state in ``work/state.json``), models into ``models``."""

    def __init__(
        self,
        robot_1: str,
        robot_2: str,
        models: Path,
        work: Path,
        budget: str = "standard",
        seed: int = 0,
        threads: int = 2,
        progress: bool = True,
        device: str = "cpu",
        cluster: str = "local",
        base_range: tuple[float, float] | None = None,
        tag: str = "any",
    ) -> None:
        known = robot_names()
        for i, robot in enumerate((robot_1, robot_2), start=1):
            if robot not in known:
                raise InvalidValueError(
                    f"robot {i}", f"must be a registered robot {list(known)}", robot
                )
        if budget not in BUDGETS:
            raise InvalidValueError("--budget", f"must be one of {sorted(BUDGETS)}", budget)
        if threads < 1:
            raise InvalidValueError("--threads", "must be >= 1", threads)
        self.base_range, self.tag = checked_range(base_range, tag), tag
        self.robots = (robot_1, robot_2)
        self.names = pair_names(robot_1, robot_2, tag)
        self.pair = self.names[0]
        self.models = models.resolve()
        self.work = work.resolve()
        self.budget_name = budget
        self.budget = BUDGETS[budget]
        self.seed = seed
        self.threads = threads
        self.progress = progress
        self.device = device
        self.cluster = parse_cluster(cluster)
        # where labels and rollouts run changes no figure, so a build may go on elsewhere
        self.cluster_args = [] if not self.cluster.is_ray else ["--cluster", cluster]
        self.state_path = self.work / "state.json"
        self.state: dict[str, Any] = self._read_state()

    # -- state ---------------------------------------------------------------------------------

    def _read_state(self) -> dict[str, Any]:
        fresh = {
            "pair": self.pair,
            "robots": list(self.robots),
            "budget": self.budget_name,
            "seed": self.seed,
            "models": str(self.models),
            "base_range": None if self.base_range is None else list(self.base_range),
            "stages": {},
        }
        if not self.state_path.exists():
            return fresh
        state = {"base_range": None, **json.loads(self.state_path.read_text())}  # older: None
        for key in ("pair", "budget", "seed", "models", "base_range"):
            if state.get(key) != fresh[key]:
                raise InvalidValueError(
                    "--work",
                    f"holds a build with {key} = {state.get(key)!r}; use another folder or the "
                    "same settings",
                    f"{key} = {fresh[key]!r}",
                )
        return state

    def _save(self) -> None:
        atomic_write(self.state_path, json.dumps(self.state, indent=2) + "\n")

    def done(self, stage: str) -> bool:
        return stage in self.state["stages"]

    # -- running ---------------------------------------------------------------------------------

    def stages(self) -> list[tuple[str, Callable[[], StageRecord]]]:
        out: list[tuple[str, Callable[[], StageRecord]]] = [
            ("check", self._check),
            ("labels", self._labels),
            ("distance", self._distance),
            ("calibrate", self._calibrate),
            ("distance-certificate", self._distance_certificate),
        ]
        for game in self.names:
            out.append((f"value:{game}", functools.partial(self._value, game)))
        for game in self.names:
            out.append((f"certify:{game}", functools.partial(self._certify, game)))
            out.append((f"falsify:{game}", functools.partial(self._falsify, game)))
        out.append(("visit", lambda: StageRecord(*visit.visit_stage(self))))
        for game in self.names:
            out.append((f"certify-visited:{game}", functools.partial(self._certify, game, True)))
        out.append(("card", self._card))
        return out

    def run(self) -> Path:
        """Run every stage not done yet; returns the pair card's path."""
        self.work.mkdir(parents=True, exist_ok=True)
        self.models.mkdir(parents=True, exist_ok=True)
        self._save()
        self._restore_manifest()
        stages = self.stages()
        bar = tqdm(stages, desc=f"pair {self.pair}", unit="stage", disable=not self.progress)
        for name, fn in bar:
            bar.set_postfix_str(name)
            if self.done(name):
                continue
            start = time.perf_counter()
            record = fn()
            record.wall_time_s = time.perf_counter() - start
            self.state["stages"][name] = asdict(record)
            self._save()
            tqdm.write(f"  {name}: done in {record.wall_time_s:.0f} s", file=sys.stderr)
        return self.models / f"{self.pair}.card.json"

    def _restore_manifest(self) -> None:
        """Rewrite a missing pair manifest from the check stage's figures (later stages need it)."""
        if not self.done("check") or (self.models / f"{self.pair}.pairs.yaml").exists():
            return
        figures = self.state["stages"]["check"]["figures"]
        low, high = figures["base_range_m"]
        write_manifest(self.models, self.robots, (low, high), figures["variant"], self.tag)

    def _env(self) -> dict[str, str]:
        env = dict(os.environ)
        others = [p for p in registry.model_dirs_env() if p != str(self.models)]
        env[registry.MODELS_ENV] = os.pathsep.join([str(self.models), *others])
        env["OMP_NUM_THREADS"] = str(self.threads)
        return env

    def nehmo(self, stage: str, args: list[str]) -> str:
        """Run ``nehmo ARGS`` in a fresh process (the pair registered through the model folder);
        its output goes to ``work/logs/<stage>.log``; returns the command as typed."""
        command = "nehmo " + shlex.join(args)
        log_dir = self.work / "logs"
        log_dir.mkdir(parents=True, exist_ok=True)
        log = log_dir / f"{stage.replace(':', '_')}.log"
        with log.open("a") as out:
            out.write(f"$ {command}\n")
            out.flush()
            proc = subprocess.run(
                [sys.executable, "-m", "nehmo_core.cli", *args],
                env=self._env(),
                stdout=out,
                stderr=out if not self.progress else None,
                check=False,
            )
        if proc.returncode != 0:
            tail = log.read_text().strip().splitlines()[-3:]
            raise NehmoError(
                f"stage {stage} failed: {command} exited with {proc.returncode}; "
                f"last lines of {log}: {' | '.join(tail)}"
            )
        return command

    def probe(self, what: str, args: list[str]) -> Any:
        """Run a probe (:mod:`.probes`) in a fresh process and return its JSON result."""
        proc = subprocess.run(
            [sys.executable, "-m", "nehmo_core.pairs.probes", *args],
            env=self._env(),
            capture_output=True,
            text=True,
        )
        at = proc.stdout.rfind(RESULT)
        if proc.returncode != 0 or at < 0:
            raise NehmoError(f"{what} failed: {proc.stderr.strip()[-400:]}")
        return json.loads(proc.stdout[at + len(RESULT) :].splitlines()[0])

    # -- stages ------------------------------------------------------------------------------------

    def _check(self) -> StageRecord:
        from nehmo_core.pairs.reach import base_range

        figures: dict[str, Any] = {
            "robots": {
                n: robot_figures(n, self.budget.reach_samples, self.seed) for n in self.robots
            }
        }
        low, high = base_range(*(figures["robots"][n]["reach_m"] for n in self.robots))
        figures["reach_base_range_m"] = [low, high]
        if self.base_range is not None:  # a part of the distances the reach allows
            low, high = self.base_range
        figures["base_range_m"] = [low, high]
        write_manifest(self.models, self.robots, (low, high), "bc+sym", self.tag)
        if any("none" in figures["robots"][n]["mirror_map"] for n in self.robots):
            figures["mirror_check"] = {"variant": "bc", "why": "a robot has no mirror map"}
        else:
            n, seed = str(self.budget.mirror_samples), str(self.seed)
            args = ["mirror", self.pair, "--samples", n, "--seed", seed]
            figures["mirror_check"] = judge_mirror(self.probe(f"mirror check of {self.pair}", args))
        figures["variant"] = figures["mirror_check"]["variant"]
        write_manifest(self.models, self.robots, (low, high), figures["variant"], self.tag)
        return StageRecord([], figures)

    @property
    def variant(self) -> str:
        """The value functions' variant: ``bc+sym`` where the mirror map holds, else ``bc``."""
        return str(self.state["stages"]["check"]["figures"]["variant"])

    @property
    def slug(self) -> str:
        return self.variant.replace("+", "_")

    def _labels(self) -> StageRecord:
        b = self.budget
        data = self.work / "data"
        data.mkdir(parents=True, exist_ok=True)
        commands = []
        sets = {
            "train": (b.uniform, b.boundary, self.seed),
            "test": (b.test // 2, b.test - b.test // 2, self.seed + 1001),
            "calib": (b.calibration // 2, b.calibration - b.calibration // 2, self.seed + 2002),
        }
        for name, (uniform, boundary, seed) in sets.items():
            out = data / f"{name}.npz"
            if out.exists():
                continue
            tmp = data / f"{name}.partial.npz"
            commands.append(
                self.nehmo(
                    "labels",
                    [
                        *f"distance generate --pair {self.pair} --uniform {uniform} "
                        f"--boundary {boundary} --seed {seed} --workers {self.threads}".split(),
                        "--out",
                        str(tmp),
                        *self.cluster_args,
                    ],
                )
            )
            tmp.replace(out)
        return StageRecord(commands, {k: v[:2] for k, v in sets.items()})

    def _distance(self) -> StageRecord:
        data = self.work / "data"
        command = self.nehmo(
            "distance",
            [
                "distance", "train", "--pair", self.pair, "--data", str(data / "train.npz"),
                "--test", str(data / "test.npz"), "--hidden", self.budget.hidden, "--keypoints",
                "geometry", "--epochs", str(self.budget.epochs), "--seed", str(self.seed),
            ],
        )  # fmt: skip
        return StageRecord([command], self._distance_figures())

    def _calibrate(self) -> StageRecord:
        data = self.work / "data"
        command = self.nehmo(
            "calibrate",
            [
                "distance", "calibrate", "--pair", self.pair, "--data", str(data / "calib.npz"),
                "--test", str(data / "test.npz"), "--target", str(CALIBRATION_TARGET), "--unbiased",
            ],
        )  # fmt: skip
        return StageRecord([command], self._distance_figures())

    def _distance_figures(self) -> dict[str, Any]:
        card = json.loads((self.models / f"distance_{self.pair}.json").read_text())
        acc = card.get("accuracy_held_out", {})
        keep = ("mae_m", "mae_near_m", "p95_err_near_m", "false_safe_rate", "n", "n_near")
        return {
            "held_out": {k: acc[k] for k in keep if k in acc},
            "output_offset_m": card.get("training", {}).get("output_offset_m"),
        }

    def _distance_certificate(self) -> StageRecord:
        args = [
            "distance-certificate", self.pair,
            "--samples", str(self.budget.certificate_samples),
            "--seed", str(self.seed + 3003), "--alpha", str(self.budget.alpha),
            "--pool", str(self.work / "data" / "test.npz"),
        ]  # fmt: skip
        cert = self.probe("distance certificate", args)
        card_path = self.models / f"distance_{self.pair}.json"
        card = json.loads(card_path.read_text())
        card["certificates"] = [{**cert, "command": "nehmo pair build (distance-certificate)"}]
        atomic_write(card_path, json.dumps(card, indent=1) + "\n")
        return StageRecord([], cert)

    def _value(self, game: str) -> StageRecord:
        return StageRecord(*value_stage(self, game))

    def _certify(self, game: str, visited: bool = False) -> StageRecord:
        return StageRecord(*visit.certify_stage(self, game, visited))

    def _falsify(self, game: str) -> StageRecord:
        args = [
            "falsify", game, "--variant", self.variant,
            "--samples", str(self.budget.falsify_samples), "--seed", str(self.seed + 4004),
            *self.cluster_args,
        ]  # fmt: skip
        result = self.probe(f"falsification of {game}", args)
        return StageRecord([], result)

    def _card(self) -> StageRecord:
        stages = {k: v for k, v in self.state["stages"].items()}
        values = {k[6:]: v["figures"] for k, v in stages.items() if k[:6] == "value:"}
        unlearned = [
            unlearned_warning(
                g, f["below_boundary"]["pde"], [a["pde_loss"] for a in f.get("attempts", [])]
            )
            for g, f in values.items()
            if not f["below_boundary"].get("learned", 1)
        ]
        low_high = " ".join(f"{r:g}" for r in self.base_range or ())
        ranged = f" --base-range {low_high} --tag {self.tag}" if low_high else ""
        card = {
            "what": (
                f"pose-conditioned pair models of {self.robots[0]} and {self.robots[1]}: learned "
                f"distance distance_{self.pair}, value functions "
                + ", ".join(f"value_{g}_{self.slug}" for g in self.names)
            ),
            "command": (
                f"nehmo pair build {self.robots[0]} {self.robots[1]} --budget "
                f"{self.budget_name} --seed {self.seed} --threads {self.threads}" + ranged
            ),
            "budget": {"name": self.budget_name, **asdict(self.budget)},
            "seed": self.seed,
            "hardware": f"{self.threads} CPU threads of {os.cpu_count()} ({platform.machine()})",
            "wall_time_s": {k: v["wall_time_s"] for k, v in stages.items()},
            "total_wall_time_s": sum(v["wall_time_s"] for v in stages.values()),
            "stages": stages,
            "warnings": unlearned,
        }
        path = self.models / f"{self.pair}.card.json"
        atomic_write(path, json.dumps(card, indent=2) + "\n")
        return StageRecord([], {"card": str(path)})


CALIBRATION_TARGET = 0.009
"""False-safe rate whose offset the calibrate stage records (the distance itself stays unbiased)."""
