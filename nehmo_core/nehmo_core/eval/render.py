"""Renders of a logged episode: an animated GIF (PyBullet's CPU renderer) and a distance plot.

Everything is drawn from the log alone: the cell and goals from its metadata and goal
topics, the arms' motion from the joint states. The GIF shows the arms in their own colours,
their goal configurations as faint green ghosts, and the time and outcome in the caption; the plot
shows the minimum exact distance [m] between every pair of arms over time (PyBullet on the
collision geometry), with the outcome marked.

    python -m nehmo_core.eval.render LOG_BAG OUT_DIR [--fps 10] [--size 480x360]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pybullet as pb

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.eval.episode_log import EpisodeLog, read_episode_log
from nehmo_core.eval.metrics import evaluate_log
from nehmo_core.geometry.pybullet_world import CellWorld

__all__ = ["distance_series", "plot_distances", "render_episode", "render_gif"]

_COLOURS = [
    (0.95, 0.55, 0.15, 1.0),  # orange
    (0.20, 0.45, 0.85, 1.0),  # blue
    (0.75, 0.30, 0.65, 1.0),  # purple
    (0.85, 0.25, 0.25, 1.0),  # red
    (0.15, 0.60, 0.60, 1.0),  # teal
]
_GHOST = (0.55, 0.85, 0.55, 1.0)  # goal configurations, blended to a faint green


def _paint(world: CellWorld, arm_id: str, rgba: tuple[float, float, float, float]) -> None:
    body = world.body(arm_id)
    for link in range(-1, pb.getNumJoints(body, physicsClientId=world.client)):
        pb.changeVisualShape(body, link, rgbaColor=rgba, physicsClientId=world.client)


def _frames_at(log: EpisodeLog, fps: float) -> list[int]:
    """Indices of the logged instants closest to a ``fps`` frame clock (real-time playback)."""
    t = (log.stamps - log.stamps[0]) / 1e9
    clock = np.arange(0.0, t[-1] + 1e-9, 1.0 / fps)
    return sorted({int(np.argmin(np.abs(t - c))) for c in clock} | {len(t) - 1})


def render_gif(
    log: EpisodeLog, path: str | Path, fps: float = 10.0, size: tuple[int, int] = (480, 360)
) -> Path:
    """An animated GIF of the episode (played back in real time at ``fps`` frames per second)."""
    from PIL import Image, ImageDraw

    if not fps > 0:
        raise InvalidValueError("fps", "must be > 0", fps)
    result = evaluate_log(log)
    width, height = size
    frames = []
    with CellWorld(log.cell) as world, CellWorld(log.cell) as ghosts:
        for k, arm in enumerate(log.cell.arms):
            _paint(world, arm.arm_id, _COLOURS[k % len(_COLOURS)])
            _paint(ghosts, arm.arm_id, _GHOST)
        ghosts.set_configuration(log.goals)
        centre = np.mean([a.base.xyz for a in log.cell.arms], axis=0) + np.array([0, 0, 0.3])
        span = max(np.ptp([a.base.xyz for a in log.cell.arms], axis=0).max(), 0.6)
        view = pb.computeViewMatrixFromYawPitchRoll(
            centre.tolist(), 0.9 + 1.1 * span, 35.0, -30.0, 0.0, 2
        )
        proj = pb.computeProjectionMatrixFOV(50.0, width / height, 0.05, 20.0)
        ghost = _image(ghosts.client, width, height, view, proj)
        for i in _frames_at(log, fps):
            world.set_configuration({a: log.positions[a][i] for a in log.cell.arm_ids})
            rgb = _image(world.client, width, height, view, proj)
            blend = np.where(
                (rgb == 255).all(axis=2, keepdims=True), 0.7 * ghost + 0.3 * 255, rgb
            ).astype(np.uint8)
            image = Image.fromarray(blend)
            draw = ImageDraw.Draw(image)
            t = (log.stamps[i] - log.stamps[0]) / 1e9
            last = i == len(log.stamps) - 1
            caption = f"{log.metadata.get('row', '')}  t = {t:5.2f} s"
            if last:
                caption += f"  {result.outcome.upper()}"
            draw.text((8, 8), caption, fill=(0, 0, 0))
            frames.append(image)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    durations = [round(1000 / fps)] * len(frames)
    durations[-1] = 1500  # hold the last frame
    frames[0].save(
        out, save_all=True, append_images=frames[1:], duration=durations, loop=0, optimize=True
    )
    return out


def _image(
    client: int, width: int, height: int, view: list[float], proj: list[float]
) -> np.ndarray:
    img = pb.getCameraImage(
        width, height, view, proj, renderer=pb.ER_TINY_RENDERER, physicsClientId=client
    )
    return np.reshape(np.asarray(img[2], dtype=np.uint8), (height, width, 4))[:, :, :3]


def distance_series(log: EpisodeLog, stride: int = 1) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Times [s] and, per arm pair ``"a|b"``, the exact minimum distance [m] at each instant."""
    if stride < 1:
        raise InvalidValueError("stride", "must be >= 1", stride)
    index = list(range(0, len(log.stamps), stride))
    if index[-1] != len(log.stamps) - 1:
        index.append(len(log.stamps) - 1)
    pairs = log.cell.pairs()
    out = {f"{a}|{b}": np.empty(len(index)) for a, b in pairs}
    with CellWorld(log.cell) as world:
        for j, i in enumerate(index):
            world.set_configuration({a: log.positions[a][i] for a in log.cell.arm_ids})
            for a, b in pairs:
                out[f"{a}|{b}"][j] = world.distance(a, b)
    return (log.stamps[index] - log.stamps[0]) / 1e9, out


def episode_title(log: EpisodeLog) -> str:
    """``setup · planners · scenario seed/index`` from either log source.

    The batch runner records ``setup``, ``row`` and ``scenario_set``; the ROS bridge records
    ``scenario`` (file, episode, seed, index) and the planner kind per arm.
    """
    meta = log.metadata
    source = meta.get("scenario_set") or meta.get("scenario") or {}
    row = meta.get("row") or "/".join(str(k) for k in (meta.get("planners") or {}).values())
    where = f"seed {source['seed']} #{source['index']}" if "index" in source else "unknown"
    suffix = " (ROS)" if meta.get("source") == "ros" else ""
    return f"{meta.get('setup', log.cell.name)}{suffix} · {row} · scenario {where}"


def plot_distances(log: EpisodeLog, path: str | Path, stride: int = 1) -> Path:
    """A PNG of the minimum pairwise distance over time (every pair, and their minimum)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    result = evaluate_log(log)
    t, series = distance_series(log, stride)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    if len(series) > 1:
        for name, d in series.items():
            ax.plot(t, d, lw=0.8, alpha=0.6, label=name.replace("|", " – "))
    overall = np.min(np.stack(list(series.values())), axis=0)
    ax.plot(t, overall, color="k", lw=1.6, label="minimum over pairs")
    ax.axhline(0.0, color="r", lw=0.8, ls="--")
    ax.axvline(result.end_time, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("distance [m]")
    ax.set_title(f"{episode_title(log)} · {result.outcome} at {result.end_time:.2f} s", fontsize=9)
    ax.legend(fontsize=7, loc="upper right")
    ax.set_ylim(bottom=min(-0.02, float(overall.min()) - 0.02))
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def render_episode(
    log_path: str | Path, out_dir: str | Path, fps: float = 10.0, size: tuple[int, int] = (480, 360)
) -> list[Path]:
    """The GIF and the distance plot of one logged episode, named after the log."""
    log = read_episode_log(log_path)
    stem = Path(log_path).name.removesuffix(".mcap")
    out = Path(out_dir)
    return [
        render_gif(log, out / f"{stem}.gif", fps, size),
        plot_distances(log, out / f"{stem}_distance.png"),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m nehmo_core.eval.render", description=__doc__)
    parser.add_argument("log", type=Path, help="an episode log (bag directory)")
    parser.add_argument("out", type=Path, help="output directory")
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--size", default="480x360", help="WIDTHxHEIGHT [px]")
    args = parser.parse_args(argv)
    try:
        w, _, h = args.size.partition("x")
        outputs = render_episode(args.log, args.out, args.fps, (int(w), int(h)))
    except (NehmoError, ValueError) as exc:
        print(f"render: error: {exc}", file=sys.stderr)
        return 2
    for o in outputs:
        print(o)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
