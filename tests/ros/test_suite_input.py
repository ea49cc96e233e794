"""The demo and the orchestrator reject what every arm_planner would, before starting anything."""

from __future__ import annotations

from pathlib import Path

import pytest

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_ros.demo import main as demo_main
from nehmo_ros.suite_settings import SuiteSettings


@pytest.mark.parametrize("row", ["chomp", "nehmo/ompl", "bogus"])
def test_a_row_arm_planner_cannot_run_is_rejected(row: str) -> None:
    with pytest.raises(UnknownNameError, match="planner"):
        SuiteSettings(planner=row)


def test_model_sources_are_checked(tmp_path: Path) -> None:
    with pytest.raises(InvalidValueError, match=r"`model`.*'bogus'"):
        SuiteSettings(model="bogus")
    with pytest.raises(InvalidValueError, match="`model`"):
        SuiteSettings(model="nehmo=" + str(tmp_path / "missing"))
    for fine in ("shipped", "synthetic", "ur5_ur5", f"nehmo={tmp_path}"):
        SuiteSettings(model=fine)
    SuiteSettings(planner="nehmo/reckless")


def test_the_demo_checks_index_and_out_first(tmp_path: Path) -> None:
    with pytest.raises(InvalidValueError, match=r"`index` must be >= 0; got -1"):
        demo_main(["--index", "-1", "--out", str(tmp_path / "d")])
    a_file = tmp_path / "file"
    a_file.write_text("")
    with pytest.raises(InvalidValueError, match="`out` must be a directory"):
        demo_main(["--out", str(a_file)])
    with pytest.raises(UnknownNameError, match="planner"):
        demo_main(["--planner", "chomp", "--out", str(tmp_path / "d")])
    assert not (tmp_path / "d").exists()  # nothing written before the checks


def test_niceness_per_process() -> None:
    """The recorder and the planners get their own added niceness on top of ``nice``; the
    bridge and the lifecycle manager only ``nice``; out of [0, 19] is refused by name."""
    from nehmo_ros.suite import niceness

    s = SuiteSettings(nice=1, recorder_nice=10, planner_nice=3)
    planners = {"planner_ur5_0", "planner_ur5_1"}
    assert niceness(s, "recorder", planners) == 11
    assert niceness(s, "planner_ur5_1", planners) == 4
    assert niceness(s, "sim_bridge", planners) == 1
    assert niceness(SuiteSettings(), "planner_ur5_0", planners) == 0
    with pytest.raises(InvalidValueError, match=r"`planner_nice` must lie in \[0, 19\]; got 20"):
        SuiteSettings(planner_nice=20)
