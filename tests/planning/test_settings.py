"""The planner's settings in groups: dotted names, presets, rules, the renamed flat names."""

from __future__ import annotations

import dataclasses
import re

import pytest

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.planning.settings import (
    PAPER_OPT,
    RENAMED,
    PlannerSettings,
    parse_assignments,
)


def test_every_setting_has_a_meaning_and_a_dotted_name() -> None:
    specs = list(PlannerSettings.specs())
    assert len({name for name, *_ in specs}) == len(specs)
    for name, group, key, rule in specs:
        assert name == f"{group}.{key}" and rule.doc, name
    assert set(PlannerSettings().flat()) == {name for name, *_ in specs}


def test_every_flat_name_of_earlier_releases_maps_to_a_setting() -> None:
    names = set(PlannerSettings().flat())
    assert set(RENAMED.values()) <= names
    for old, new in RENAMED.items():
        with pytest.raises(UnknownNameError, match=re.escape(f"'{old}' is now '{new}'")):
            PlannerSettings().override({old: 1})


def test_paper_preset_turns_every_stage_off_and_nothing_else() -> None:
    paper, default = PlannerSettings.preset("paper"), PlannerSettings()
    changed = {k for k, v in paper.flat().items() if default.flat()[k] != v}
    # every stage is off in the preset; the ones off by default too (actuator) change nothing
    assert all(paper.flat()[k] == v for k, v in PAPER_OPT.items())
    assert changed == {k for k, v in PAPER_OPT.items() if default.flat()[k] != v}
    assert not paper.actuator.enabled and not paper.contact.clearance
    assert not paper.escape.enabled and not paper.self_clearance.enabled
    assert paper.hold.bound == 1.0 and paper.exact_guard.gap == 0.0
    assert paper.silent_watch.lookahead == 0.0
    # the paper's fail-safe sweeps every joint; NeHMO's keeps the ones that barely change V still
    assert paper.fail_safe.deadband == 0.0 < default.fail_safe.deadband
    assert paper.opt == default.opt and paper.solver == default.solver


def test_override_changes_one_setting_and_checks_it_in_its_group() -> None:
    s = PlannerSettings().override({"hold.bound": 0.5, "opt.t_plan": 0.08})
    assert (s.hold.bound, s.opt.t_plan) == (0.5, 0.08)
    assert dataclasses.replace(s.hold, bound=0.2) == PlannerSettings().hold
    with pytest.raises(InvalidValueError, match=r"`hold\.bound` must lie in \[0, 1\]; got 1\.5"):
        s.override({"hold.bound": 1.5})
    with pytest.raises(InvalidValueError, match=r"`opt\.t_plan` must be < opt\.t_safe"):
        s.override({"opt.t_plan": 0.5})
    with pytest.raises(UnknownNameError, match=r"hold\.bound"):
        s.override({"hold.bond": 0.5})  # a typo lists the valid names
    with pytest.raises(InvalidValueError, match=r"`exact_guard\.scales` must lie in \(0, 1\]"):
        s.override({"exact_guard.scales": (1.0, 0.0)})


def test_groups_are_typed() -> None:
    with pytest.raises(InvalidValueError, match="`hold` must be a HoldSettings"):
        PlannerSettings(hold=0.2)  # type: ignore[arg-type]


def test_command_line_assignments_are_typed_by_the_setting() -> None:
    got = parse_assignments(
        [
            "opt.t_plan=0.08",
            "escape.enabled=false",
            "escape.stall_ticks=20",
            "solver.name=ipopt",
        ]
    )
    assert got == {
        "opt.t_plan": 0.08,
        "escape.enabled": False,
        "escape.stall_ticks": 20,
        "solver.name": "ipopt",
    }
    assert parse_assignments(["exact_guard.scales=1,0.5"]) == {"exact_guard.scales": (1.0, 0.5)}
    with pytest.raises(InvalidValueError, match=r"escape\.enabled must be true or false"):
        parse_assignments(["escape.enabled=maybe"])
    with pytest.raises(InvalidValueError, match=r"escape\.stall_ticks must be an integer"):
        parse_assignments(["escape.stall_ticks=1.5"])
    with pytest.raises(InvalidValueError, match=r"GROUP\.FIELD=VALUE"):
        parse_assignments(["opt.t_plan"])
    with pytest.raises(UnknownNameError, match=r"'t_plan' is now 'opt\.t_plan'"):
        parse_assignments(["t_plan=0.08"])


def test_the_settings_page_is_current() -> None:
    from pathlib import Path

    from nehmo_core.planning.settings.reference import markdown

    page = Path(__file__).resolve().parents[2] / "docs" / "settings.md"
    assert page.read_text() == markdown(), (
        "docs/settings.md drifted: ./run python -m nehmo_core.planning.settings.reference "
        "docs/settings.md"
    )


def test_a_removed_setting_says_why() -> None:
    with pytest.raises(UnknownNameError, match=r"'fail_safe\.kind' no longer exists: the maximin"):
        PlannerSettings().override({"fail_safe.kind": "maximin"})
