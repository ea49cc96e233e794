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
