"""Trial plans: seeded, complete, split in two, written once and reused."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from experiment import PlanError, load_or_create_plan, make_plan, participant_seed, plan_path


def test_plan_holds_every_stimulus_once_split_into_two_sessions(design, rng):
    plan = make_plan(design, "P01", rng, seed=1)
    assert len(plan) == 162 and plan["stimulus_id"].is_unique
    assert plan.groupby("session").size().to_dict() == {1: 81, 2: 81}
    assert plan.groupby("session")["trial"].apply(lambda t: sorted(t) == list(range(1, 82))).all()
    assert list(plan["order"]) == list(range(1, 163))


def test_plan_is_reproducible_from_seed_and_differs_between_participants(design):
    a = make_plan(design, "P01", np.random.default_rng(participant_seed("P01")), seed=0)
    b = make_plan(design, "P01", np.random.default_rng(participant_seed("P01")), seed=0)
    c = make_plan(design, "P02", np.random.default_rng(participant_seed("P02")), seed=0)
    assert list(a["stimulus_id"]) == list(b["stimulus_id"])
    assert list(a["stimulus_id"]) != list(c["stimulus_id"])


def test_plan_file_is_written_once_and_reused(design, tmp_path):
    first = load_or_create_plan(design, "P07", tmp_path)
    path = plan_path(tmp_path, "P07")
    mtime = path.stat().st_mtime_ns
    again = load_or_create_plan(design, "P07", tmp_path)
    pd.testing.assert_frame_equal(first, again)
    assert path.stat().st_mtime_ns == mtime
    assert not list(path.parent.glob("*.tmp"))


def test_plan_for_another_design_is_refused(design, tmp_path):
    plan = load_or_create_plan(design, "P03", tmp_path)
    plan.iloc[:-1].to_csv(plan_path(tmp_path, "P03"), index=False)
    with pytest.raises(PlanError, match="exactly once"):
        load_or_create_plan(design, "P03", tmp_path)


@pytest.mark.parametrize("bad", ["P 01", "", "x" * 33, "P01/..", "Ü1"])
def test_bad_participant_ids_are_refused(design, tmp_path, bad):
    with pytest.raises(ValueError, match="participant id"):
        load_or_create_plan(design, bad, tmp_path)
