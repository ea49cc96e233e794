"""Evaluation (paper § IV): scenario sets, the batch episode runner, metrics
computed from the logs (rosbag2 bags), the ``nehmo evaluate`` command, tables beside the
paper's, renders.

- :mod:`.setups`: the setups (cell, time limit, success rule, timed arms) and planner rows.
- :mod:`.scenario_sets`: seeded scenario sets as JSON files; the UR5-Kinova challenging filter.
- :mod:`.episode`: :func:`run_episode` — 25 Hz control, one-tick planning latency, exact
  collision checks at sub-steps, a bag per episode (:mod:`.episode_log`, :mod:`.telemetry`).
- :mod:`.metrics`: :func:`evaluate_log` (an episode's result from its log) and :func:`aggregate`.
- :mod:`.planners`: the planners of a row (value models from
  :mod:`nehmo_core.planning.models.registry`); :mod:`.batch`: process pool.
- :mod:`.report`, :mod:`.paper`: JSON and markdown summaries with the paper's numbers.
- :mod:`.render`: a GIF and a distance plot of an episode, from its log.
"""

from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.episode_log import EpisodeLog, EpisodeLogError, read_episode_log
from nehmo_core.eval.metrics import EpisodeResult, RowMetrics, aggregate, evaluate_log
from nehmo_core.eval.setups import SETUPS, Setup, get_setup, parse_row

__all__ = [
    "SETUPS",
    "EpisodeLog",
    "EpisodeLogError",
    "EpisodeResult",
    "EpisodeSettings",
    "RowMetrics",
    "Setup",
    "aggregate",
    "evaluate_log",
    "get_setup",
    "parse_row",
    "read_episode_log",
    "run_episode",
]
