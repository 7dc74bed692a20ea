"""bench/blind/score.py (issue 43 item 3): verdict classes, intervals, resuming and locks.

The scorer is loaded by path (a script). Its full run goes through the project's CLIs and takes
minutes per case; these tests check the parts that decide the table without running a diagnosis.
"""

from __future__ import annotations

import importlib.util
import json
import os
from pathlib import Path

import pytest

SCORE = Path(__file__).resolve().parents[2] / "bench" / "blind" / "score.py"


@pytest.fixture(scope="module")
def score():
    spec = importlib.util.spec_from_file_location("blind_score", SCORE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize(("verdict", "kind", "names"), [
    ("no_gap_that_matters", "excluded", []),
    ("inconclusive", "inconclusive", []),
    ("no_significant_gap", "legacy", []),
    ("unexplained", "gap", ["unexplained"]),
    ("warmup_drift + black_offset", "gap", ["warmup_drift", "black_offset"]),
    (None, "crash", []),
])
def test_verdicts_fall_in_issue_43s_classes(score, verdict, kind, names):
    assert score.classify(verdict) == (kind, names)


def test_wilson_interval_matches_the_closed_form(score):
    # Wilson (1927) with z = 1.96: 0 of 1 -> [0, 0.7935]; 5 of 10 -> [0.2366, 0.7634].
    assert score.wilson(0, 1) == pytest.approx((0.0, 0.7935), abs=1e-4)
    assert score.wilson(5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)


def fake_case(root, layer, name, verdict, truth):
    folder = root / layer / name
    (folder / "REPORT").mkdir(parents=True)
    (folder / "REPORT" / "diagnosis.json").write_text(json.dumps({"verdict": verdict}))
    (folder / "truth.json").write_text(json.dumps(truth))
    return folder


def test_a_diagnosed_case_is_read_not_recomputed(score, tmp_path):
    truth = {"expected": "black_offset + warmup_drift", "in_catalogue": True,
             "size_in_tolerances": 2.0}
    folder = fake_case(tmp_path, "display", "offset_warmup-x2-full-s7",
                       "warmup_drift + black_offset", truth)
    before = sorted(p.name for p in folder.rglob("*"))
    r = score.score_one("display", "offset_warmup", 2.0, "full", 7, tmp_path,
                        timeout_s=5, force=False)
    assert r["reused"] and r["kind"] == "gap"
    assert r["expected"] == ["black_offset", "warmup_drift"]
    assert sorted(p.name for p in folder.rglob("*")) == before  # nothing run or written
    rows = {row[0]: row for row in score.rows("display", [r])}
    assert len(rows["R2n"][3]) == 1 and len(rows["R3"][3]) == 0


def test_an_observer_effect_a_person_can_absorb_counts_in_r3_not_r3w(score, tmp_path):
    # rest_drift at 1x: total size 1.0 tolerance, 0.55 of it left once each person's own mean
    # change is taken out; slider_swap at 1x: 1.0 within. Both read no_gap_that_matters.
    recs = []
    for name, within in (("rest_drift-x1-n20-s5", 0.55), ("slider_swap-x1-n20-s5", 1.0)):
        fake_case(tmp_path, "observer", name, "no_gap_that_matters",
                  {"expected": "unexplained", "size_in_tolerances": 1.0,
                   "size_within_person_in_tolerances": within})
        case = name.split("-")[0]
        recs.append(score.score_one("observer", case, 1.0, "n20", 5, tmp_path, timeout_s=5,
                                    force=False))
    rows = {row[0]: row for row in score.rows("observer", recs)}
    assert (len(rows["R3"][3]), len(rows["R3"][4])) == (2, 2)
    assert [r["case"] for r in rows["R3w"][4]] == ["slider_swap"]
    text, out = score.table(recs)
    assert "R3w" in text and {"R3", "R3w"} <= {o["row"] for o in out}
    fake_case(tmp_path, "display", "clean-full-s3", "no_gap_that_matters",
              {"expected": "none", "size_in_tolerances": 0.0})
    clean = score.score_one("display", "clean", None, "full", 3, tmp_path, timeout_s=5,
                            force=False)
    assert "R3w" not in score.table([clean])[0]  # no unabsorbed size in the display's truth


def test_a_render_effect_a_refitted_ward_can_absorb_counts_in_r3_not_r3w(score, tmp_path):
    # lens_flare at 1x: 1.0 tolerance against the true material, 0.69 against the Ward that
    # best fits the fit's lights (truth.json's size_beyond_fit); interreflection at 2x: 1.9.
    recs = []
    for name, m, beyond in (("lens_flare-x1-L48-s5", 1.0, 0.69),
                            ("interreflection-x2-L48-s5", 2.0, 1.9)):
        fake_case(tmp_path, "render", name, "no_gap_that_matters",
                  {"expected": "unexplained", "size_in_tolerances": m,
                   "size_beyond_fit_in_tolerances": beyond})
        recs.append(score.score_one("render", name.split("-")[0], m, "L48", 5, tmp_path,
                                    timeout_s=5, force=False))
    rows = {row[0]: row for row in score.rows("render", recs)}
    assert (len(rows["R3"][3]), len(rows["R3"][4])) == (2, 2)
    assert [r["case"] for r in rows["R3w"][4]] == ["interreflection"]
    assert "unabsorbed" in score.table(recs)[0]


def test_a_case_locked_by_a_live_runner_is_left_to_it(score, tmp_path):
    lock = tmp_path / ".locks" / "display-clean-full-s3.lock"
    lock.parent.mkdir(parents=True)
    lock.write_text(f"{os.getpid()}@{__import__('socket').gethostname()}")
    r = score.score_one("display", "clean", None, "full", 3, tmp_path, timeout_s=5, force=False)
    assert r["kind"] == "pending" and not (tmp_path / "display" / "clean-full-s3").exists()
    assert lock.exists()


def test_a_stale_lock_is_taken_over(score, tmp_path):
    lock = tmp_path / "x.lock"
    lock.write_text(f"999999999@{__import__('socket').gethostname()}")
    with score.Lock(lock) as held:
        assert held.held
    assert not lock.exists()


def test_the_plan_runs_effects_at_the_full_size_and_no_effect_cases_at_every_size(score):
    args = score.argparse.Namespace(
        layers=["observer"], cases=["none", "gloss_depth"], multiples=[1.0, 2.0],
        participants=[20, 3], runs=["full"], lights=[48], all_sizes=False, seeds=[0, 1])
    jobs = score.plan(args)
    assert sorted({(c, m, s) for _, c, m, s, _ in jobs}) == [
        ("gloss_depth", 1.0, "n20"), ("gloss_depth", 2.0, "n20"),
        ("none", None, "n20"), ("none", None, "n3")]
    assert len(jobs) == 8


def test_the_render_misfit_column_is_the_misfit_the_verdict_judged(score):
    """Render: the plain simulation's misfit net of the photos' noise (``remaining.size_before``),
    not the held-out RMS with the camera's noise in it; the other layers' own fields first."""
    render = {"remaining": {"size": 1.13, "size_before": 1.23}, "misfit_pct_before": 4.01,
              "misfit_before": float("nan"), "misfit": {}}
    assert score.reported_misfit(render) == pytest.approx(1.23)
    assert score.reported_misfit({"remaining": {"size": 0.4}, "misfit_pct_before": 3.0}) == 0.4
    assert score.reported_misfit({"misfit_before": 0.21, "remaining": {"size": 0.3}}) == 0.21
    assert score.reported_misfit({"misfit": {"size_pct_before": 0.8},
                                  "remaining": {"size": 0.5}}) == 0.8
