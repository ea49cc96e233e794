"""``nehmo pair build A B``: from two robot descriptions to a certified, pose-conditioned pair.

One command runs every stage of a pair's models, each a command a user could type, in a work
folder that remembers what is done (run it again and it goes on where it stopped):

1. ``check``: both robots load, have keypoints and a base-yaw first joint; the mirror map of
   each is found by search and verified on the exact geometry (the pair distance of mirrored
   states equals the original's); each arm's reach fixes the base distances that can touch
   (:mod:`.reach`). Writes the pair manifest (``<pair>.pairs.yaml``) into the model folder.
2. ``labels``: PyBullet distance labels (training, held-out and calibration sets, own seeds).
3. ``distance``: the conditioned learned distance (``nehmo distance train``).
4. ``calibrate``: its conservative offset (``nehmo distance calibrate``).
5. ``distance-certificate``: the learned distance on exact contact states (α, β).
6. ``value:<game>``: the conditioned ``bc+sym`` value function of each side (one for a pair of
   the same robot; both games ``A_B_any`` and ``B_A_any`` otherwise), copied to the folder.
7. ``certify:<game>``: ``nehmo verify`` over uniform states at the planner's ``t_safe``,
   recorded in the model card.
8. ``falsify:<game>``: states the planner would call safe (``V(t_safe) ≥ ε``) rolled out against
   every adversary on the exact geometry: the contact rate and its bound.
9. ``card``: the pair card ``<pair>.card.json``: every command, seed, wall time and figure.

The model folder is where the pair's files go (``--models``, default the first folder of
``NEHMO_MODELS``); NeHMO finds the pair there when that folder is in ``NEHMO_MODELS``.
"""

from __future__ import annotations

import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import yaml
from tqdm import tqdm

from nehmo_core.errors import InvalidValueError, ModelFileError, NehmoError
from nehmo_core.robots import registry
from nehmo_core.robots.descriptions import robot_names

__all__ = ["BUDGETS", "Budget", "PairBuild", "pair_names"]


@dataclass(frozen=True)
class Budget:
    """How much data and training a build spends (``standard``: the shipped models' scale)."""

    uniform: int
    boundary: int
    test: int  # held-out samples (half uniform, half boundary)
    calibration: int  # calibration samples (half uniform, half boundary)
    hidden: str
    epochs: int
    value_samples: str
    value_preset: str
    certificate_samples: int
    alpha: float  # the certificates' target violation probability (β = 1e-3)
    search_samples: int
    falsify_samples: int
    mirror_samples: int
    reach_samples: int


BUDGETS: dict[str, Budget] = {
    "standard": Budget(
        uniform=400_000,
        boundary=800_000,
        test=60_000,
        calibration=80_000,
        hidden="256,256,256",
        epochs=40,
        value_samples="20M",
        value_preset="cpu_12d",
        certificate_samples=3000,
        alpha=0.01,
        search_samples=500,
        falsify_samples=3000,
        mirror_samples=2000,
        reach_samples=4000,
    ),
    # The pipeline end to end in minutes (tests, trying a robot): models too small to plan with.
    "tiny": Budget(
        uniform=3000,
        boundary=3000,
        test=1000,
        calibration=2000,
        hidden="32,32",
        epochs=1,
        value_samples="20k",
        value_preset="cpu",
        certificate_samples=60,
        alpha=0.2,
        search_samples=30,
        falsify_samples=40,
        mirror_samples=100,
        reach_samples=200,
    ),
}


def pair_names(robot_1: str, robot_2: str) -> tuple[str, ...]:
    """The pair (and, for two robots, the swapped game) a build makes: ``A_B_any`` first."""
    first = f"{robot_1}_{robot_2}_any"
    return (first,) if robot_1 == robot_2 else (first, f"{robot_2}_{robot_1}_any")


def default_models_dir() -> Path:
    """The first folder of ``NEHMO_MODELS``, else ``./nehmo_models``."""
    dirs = [p for p in os.environ.get(registry.MODELS_ENV, "").split(os.pathsep) if p]
    return Path(dirs[0]) if dirs else Path("nehmo_models")


@dataclass
class StageRecord:
    name: str
    wall_time_s: float
    commands: list[str]
    figures: dict[str, Any]


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
        self.robots = (robot_1, robot_2)
        self.names = pair_names(robot_1, robot_2)
        self.pair = self.names[0]
        self.models = models.resolve()
        self.work = work.resolve()
        self.budget_name = budget
        self.budget = BUDGETS[budget]
        self.seed = seed
        self.threads = threads
        self.progress = progress
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
            "stages": {},
        }
        if not self.state_path.exists():
            return fresh
        state = json.loads(self.state_path.read_text())
        for key in ("pair", "budget", "seed", "models"):
            if state.get(key) != fresh[key]:
                raise InvalidValueError(
                    "--work",
                    f"holds a build with {key} = {state.get(key)!r}; use another folder or the "
                    "same settings",
                    f"{key} = {fresh[key]!r}",
                )
        return state

    def _save(self) -> None:
        self.work.mkdir(parents=True, exist_ok=True)
        tmp = self.state_path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.state, indent=2) + "\n")
        tmp.replace(self.state_path)

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
            out.append((f"value:{game}", lambda g=game: self._value(g)))
        for game in self.names:
            out.append((f"certify:{game}", lambda g=game: self._certify(g)))
            out.append((f"falsify:{game}", lambda g=game: self._falsify(g)))
        out.append(("card", self._card))
        return out

    def run(self) -> Path:
        """Run every stage not done yet; returns the pair card's path."""
        self.work.mkdir(parents=True, exist_ok=True)
        self.models.mkdir(parents=True, exist_ok=True)
        self._save()
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

    def _env(self) -> dict[str, str]:
        env = dict(os.environ)
        dirs = [str(self.models)] + [
            p
            for p in env.get(registry.MODELS_ENV, "").split(os.pathsep)
            if p and Path(p).resolve() != self.models
        ]
        env[registry.MODELS_ENV] = os.pathsep.join(dirs)
        env["OMP_NUM_THREADS"] = str(self.threads)
        return env

    def _nehmo(self, stage: str, args: list[str]) -> str:
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

    def _python(self, what: str, code: str) -> Any:
        """Run ``code`` in a fresh process (the pair registered through the model folder) and
        return the JSON it printed after :data:`RESULT` (PyBullet prints to stdout too)."""
        code = f"RESULT = {RESULT!r}\n" + code
        proc = subprocess.run(
            [sys.executable, "-c", code], env=self._env(), capture_output=True, text=True
        )
        at = proc.stdout.rfind(RESULT)
        if proc.returncode != 0 or at < 0:
            raise NehmoError(f"{what} failed: {proc.stderr.strip()[-400:]}")
        return json.loads(proc.stdout[at + len(RESULT) :].splitlines()[0])

    # -- stages ------------------------------------------------------------------------------------

    def _check(self) -> StageRecord:
        from nehmo_core.geometry.symmetry import find_mirror_map
        from nehmo_core.pairs.reach import base_range, horizontal_reach
        from nehmo_core.planning.models.pair_frame import base_yaw_joint
        from nehmo_core.robots.loader import load_robot

        figures: dict[str, Any] = {"robots": {}}
        reaches = []
        for name in dict.fromkeys(self.robots):
            robot = load_robot(name)
            if not robot.facts.keypoints:
                raise ModelFileError(
                    f"robot {name!r} has no keypoints (facts.keypoints in its robot.yaml): the "
                    "learned distance is built on them; list the link frames along the arm"
                )
            if base_yaw_joint(robot) is None:
                raise ModelFileError(
                    f"robot {name!r}: its first joint does not turn the arm about the base's "
                    "vertical axis, so one model cannot serve every layout"
                )
            try:
                mirror = find_mirror_map(robot)
                found: dict[str, Any] = {"sign": list(mirror.sign), "offset": list(mirror.offset)}
            except NehmoError as exc:
                found = {"none": str(exc)}
            reach = horizontal_reach(robot, self.budget.reach_samples, self.seed)
            figures["robots"][name] = {"dof": robot.dof, "mirror_map": found, "reach_m": reach}
        for name in self.robots:
            reaches.append(figures["robots"][name]["reach_m"])
        low, high = base_range(*reaches)
        figures["base_range_m"] = [low, high]
        self._write_manifest((low, high), "bc+sym")
        if any("none" in figures["robots"][n]["mirror_map"] for n in self.robots):
            figures["mirror_check"] = {"variant": "bc", "why": "a robot has no mirror map"}
        else:
            figures["mirror_check"] = self._mirror_check()
        figures["variant"] = figures["mirror_check"]["variant"]
        self._write_manifest((low, high), figures["variant"])
        return StageRecord("check", 0.0, [], figures)

    @property
    def variant(self) -> str:
        """The value functions' variant: ``bc+sym`` where the mirror map holds, else ``bc``."""
        return str(self.state["stages"]["check"]["figures"]["variant"])

    @property
    def slug(self) -> str:
        return self.variant.replace("+", "_")

    def _write_manifest(self, base_range: tuple[float, float], variant: str) -> None:
        entries: list[dict[str, Any]] = [
            {
                "name": self.pair,
                "robots": list(self.robots),
                "conditioned": True,
                "base_range": [float(base_range[0]), float(base_range[1])],
                "values": [variant],
            }
        ]
        if len(self.names) == 2:
            entries.append(
                {
                    "name": self.names[1],
                    "robots": [self.robots[1], self.robots[0]],
                    "swapped": self.pair,
                    "values": [variant],
                }
            )
        path = self.models / f"{self.pair}{registry.MANIFEST_SUFFIX}"
        header = (
            f"# Written by nehmo pair build {self.robots[0]} {self.robots[1]}: the pair's models "
            "are the files beside it.\n"
        )
        path.write_text(header + yaml.safe_dump({"pairs": entries}, sort_keys=False))

    def _mirror_check(self) -> dict[str, Any]:
        """The pair distance of random states and of their mirror images, on exact geometry."""
        code = (
            "import json, sys, numpy as np\n"
            "from nehmo_core.geometry import distance_data as dd\n"
            "from nehmo_core.hjr.systems.arm_pairs import pair_symmetry\n"
            f"pair, n, seed = {self.pair!r}, {self.budget.mirror_samples}, {self.seed}\n"
            "rng = np.random.default_rng(seed)\n"
            "q = dd.uniform_samples(pair, n, rng)\n"
            "f = pair_symmetry(pair)\n"
            "m = q.copy(); m[:, : len(f.sign)] = f.apply(q[:, : len(f.sign)])\n"
            "yaw = rng.uniform(-np.pi, np.pi, size=(n, 2))\n"
            "d = dd.exact_distances(pair, np.c_[q, yaw])\n"
            "dm = dd.exact_distances(pair, np.c_[m, -yaw])\n"
            "near = np.abs(d) < 0.3\n"
            "diff = np.abs(d - dm)[near]\n"
            "print(RESULT, json.dumps({'states': n, 'near_contact_states': int(near.sum()),"
            " 'mean_abs_diff_near_m': float(diff.mean()) if diff.size else 0.0,"
            " 'max_abs_diff_near_m': float(diff.max()) if diff.size else 0.0}))\n"
        )
        result = self._python(f"mirror check of {self.pair}", code)
        symmetric = result["mean_abs_diff_near_m"] <= MIRROR_TOLERANCE
        result["variant"] = "bc+sym" if symmetric else "bc"
        result["why"] = (
            f"mean |d(x) - d(f(x))| within 0.3 m of contact "
            f"{1000 * result['mean_abs_diff_near_m']:.1f} mm "
            f"{'<=' if symmetric else '>'} {1000 * MIRROR_TOLERANCE:.0f} mm: "
            + ("the mirror map holds; bc+sym" if symmetric else "no exact mirror map; bc")
        )
        return result

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
                self._nehmo(
                    "labels",
                    [
                        "distance",
                        "generate",
                        "--pair",
                        self.pair,
                        "--uniform",
                        str(uniform),
                        "--boundary",
                        str(boundary),
                        "--seed",
                        str(seed),
                        "--workers",
                        str(self.threads),
                        "--out",
                        str(tmp),
                    ],
                )
            )
            tmp.replace(out)
        return StageRecord("labels", 0.0, commands, {k: v[:2] for k, v in sets.items()})

    def _distance(self) -> StageRecord:
        data = self.work / "data"
        command = self._nehmo(
            "distance",
            [
                "distance", "train", "--pair", self.pair, "--data", str(data / "train.npz"),
                "--test", str(data / "test.npz"), "--hidden", self.budget.hidden,
                "--epochs", str(self.budget.epochs), "--seed", str(self.seed),
            ],
        )  # fmt: skip
        return StageRecord("distance", 0.0, [command], self._distance_figures())

    def _calibrate(self) -> StageRecord:
        data = self.work / "data"
        command = self._nehmo(
            "calibrate",
            [
                "distance", "calibrate", "--pair", self.pair, "--data", str(data / "calib.npz"),
                "--test", str(data / "test.npz"), "--target", str(CALIBRATION_TARGET),
            ],
        )  # fmt: skip
        return StageRecord("calibrate", 0.0, [command], self._distance_figures())

    def _distance_card(self) -> Path:
        return self.models / f"distance_{self.pair}.json"

    def _distance_figures(self) -> dict[str, Any]:
        card = json.loads(self._distance_card().read_text())
        acc = card.get("accuracy_held_out", {})
        keep = ("mae_m", "mae_near_m", "p95_err_near_m", "false_safe_rate", "n", "n_near")
        return {
            "held_out": {k: acc[k] for k in keep if k in acc},
            "output_offset_m": card.get("training", {}).get("output_offset_m"),
        }

    def _distance_certificate(self) -> StageRecord:
        code = (
            "import json, numpy as np\n"
            "from nehmo_core.geometry.distance_model import load_distance_model\n"
            "from nehmo_core.hjr.systems import make_system\n"
            "from nehmo_core.verify.distance import certify_distance\n"
            "from nehmo_core.verify.distributions import UniformBox\n"
            "from nehmo_core.verify.truth import exact_margin\n"
            f"pair, n = {self.pair!r}, {self.budget.certificate_samples}\n"
            f"seed = {self.seed + 3003}\n"
            "system = make_system(pair); margin = exact_margin(system)\n"
            "cert = certify_distance(load_distance_model(pair), margin, UniformBox(system),"
            f" np.random.default_rng(seed), samples=n, alpha={self.budget.alpha})\n"
            "margin.close()\n"
            "print(RESULT, json.dumps({**cert.to_dict(), 'seed': seed}))\n"
        )
        cert = self._python("distance certificate", code)
        card_path = self._distance_card()
        card = json.loads(card_path.read_text())
        card["certificates"] = [{**cert, "command": "nehmo pair build (distance-certificate)"}]
        card_path.write_text(json.dumps(card, indent=1) + "\n")
        return StageRecord("distance-certificate", 0.0, [], cert)

    def _value(self, game: str) -> StageRecord:
        run = self.work / f"value_{game}"
        args = [
            "train", "--system", game, "--variant", self.variant,
            "--preset", self.budget.value_preset,
            "--samples", self.budget.value_samples, "--seed", str(self.seed),
            "--threads", str(self.threads), "--out", str(run),
        ]  # fmt: skip
        if (run / "checkpoint.safetensors").exists() and not (run / "model.safetensors").exists():
            args.append("--resume")
        command = self._nehmo(f"value:{game}", args)
        target = self.models / f"value_{game}_{self.slug}"
        meta = json.loads((run / "model.json").read_text())
        meta.setdefault("card", {}).update(
            {
                "what": f"neural HJR avoid value function of {game} (pose-conditioned)",
                "training": command,
                "boundary": f"l(x) = learned distance distance_{self.pair} (frozen)",
                "hardware": f"{self.threads} CPU threads ({platform.machine()})",
                "pair_card": f"{self.pair}.card.json",
            }
        )
        shutil.copyfile(run / "model.safetensors", target.with_suffix(".safetensors"))
        target.with_suffix(".json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
        figures = {"samples": meta.get("samples"), "train_wall_time_s": meta.get("wall_seconds")}
        return StageRecord(f"value:{game}", 0.0, [command], figures)

    def _certify(self, game: str) -> StageRecord:
        from nehmo_core.planning.settings import PlannerSettings

        tau = PlannerSettings().opt.t_safe
        out = self.work / "certificates"
        command = self._nehmo(
            f"certify:{game}",
            [
                "verify", "--model", game, "--variant", self.variant,
                "--tau", f"{tau:g}", "--distribution", "uniform",
                "--samples", str(self.budget.certificate_samples),
                "--alpha", str(self.budget.alpha),
                "--search-samples", str(self.budget.search_samples),
                "--seed", str(self.seed), "--out", str(out), "--card",
            ],
        )  # fmt: skip
        meta = json.loads((self.models / f"value_{game}_{self.slug}.json").read_text())
        certs = [c for c in meta["card"].get("certificates", []) if abs(c["tau"] - tau) < 1e-9]
        keep = ("delta", "violations", "samples", "epsilon", "certified", "accepted_share")
        return StageRecord(
            f"certify:{game}", 0.0, [command], {"tau": tau, **{k: certs[-1][k] for k in keep}}
        )

    def _falsify(self, game: str) -> StageRecord:
        code = (
            "import json, numpy as np\n"
            "from nehmo_core.hjr import load_value_function\n"
            "from nehmo_core.planning.settings import PlannerSettings\n"
            "from nehmo_core.verify.bound import violation_bound\n"
            "from nehmo_core.verify.certify import VerifySettings, worst_margins\n"
            "from nehmo_core.verify.distributions import UniformBox, draw_level_set\n"
            "from nehmo_core.verify.truth import exact_margin\n"
            f"game, n, seed = {game!r}, {self.budget.falsify_samples}, {self.seed + 4004}\n"
            "opt = PlannerSettings().opt; tau = opt.t_safe\n"
            f"value = load_value_function(game, variant={self.variant!r})\n"
            "certs = value.card.get('certificates', ())\n"
            "eps = max([opt.epsilon, *(c['delta'] for c in certs if abs(c['tau'] - tau) < 1e-6)])\n"
            "rng = np.random.default_rng(seed); margin = exact_margin(value.system)\n"
            "x, _, share = draw_level_set(value, UniformBox(value.system), tau, eps, n, rng)\n"
            "m, who = worst_margins(value, margin, x, VerifySettings(tau=tau), rng, 'falsify')\n"
            "margin.close(); k = int((m <= 0).sum())\n"
            "print(RESULT, json.dumps({'tau': tau, 'epsilon': eps, 'states': int(len(x)),"
            " 'contacts': k,"
            " 'rate': k / len(x), 'bound': violation_bound(len(x), k, 1e-3), 'seed': seed,"
            " 'accepted_share': share}))\n"
        )
        result = self._python(f"falsification of {game}", code)
        return StageRecord(f"falsify:{game}", 0.0, [], result)

    def _card(self) -> StageRecord:
        stages = {k: v for k, v in self.state["stages"].items()}
        card = {
            "what": (
                f"pose-conditioned pair models of {self.robots[0]} and {self.robots[1]}: learned "
                f"distance distance_{self.pair}, value functions "
                + ", ".join(f"value_{g}_{self.slug}" for g in self.names)
            ),
            "command": (
                f"nehmo pair build {self.robots[0]} {self.robots[1]} --budget "
                f"{self.budget_name} --seed {self.seed} --threads {self.threads}"
            ),
            "budget": {"name": self.budget_name, **asdict(self.budget)},
            "seed": self.seed,
            "hardware": f"{self.threads} CPU threads of {os.cpu_count()} ({platform.machine()})",
            "wall_time_s": {k: v["wall_time_s"] for k, v in stages.items()},
            "total_wall_time_s": sum(v["wall_time_s"] for v in stages.values()),
            "stages": stages,
        }
        path = self.models / f"{self.pair}.card.json"
        path.write_text(json.dumps(card, indent=2) + "\n")
        return StageRecord("card", 0.0, [], {"card": str(path)})


RESULT = "NEHMO-RESULT "
MIRROR_TOLERANCE = 0.002
"""[m] Largest mean change of the exact pair distance under the mirror maps, within 0.3 m of
contact, for which a build trains ``bc+sym`` (the UR5's meshes: 0.7 mm); above it, ``bc``."""
CALIBRATION_TARGET = 0.009
"""False-safe rate the learned distance's offset is calibrated to (the shipped models')."""


def describe(state: dict[str, Any]) -> str:
    """A few lines on a build's progress (``nehmo pair status``)."""
    lines = [
        f"pair {state['pair']} ({state['budget']}, seed {state['seed']}): "
        f"models in {state['models']}"
    ]
    for name, rec in state["stages"].items():
        lines.append(f"  {name}: {rec['wall_time_s']:.0f} s")
    return "\n".join(lines)
