"""Observer-layer gap diagnosis: parameter recovery, blind identification, the test of what
remains, stability across seeds, the fitted simulation as base, warnings, report."""

from __future__ import annotations

import ast
import stat
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from analysis.gap import GapError, diagnose, holm
from analysis.gap.__main__ import main
from analysis.gap.observer import base_from_params, to_slider_units
from analysis.gapbench import inject
from analysis.gapbench.bench_observer import HarderCase, generate_sessions
from experiment import load_observer_params, make_observer, simulate_dataset
from studydesign import load_design

DESIGN = load_design()
GAP_DIR = Path(__file__).resolve().parents[3] / "analysis" / "gap"
TOML = Path(__file__).resolve().parents[3] / "experiment" / "observers.toml"


def _diag(effect, strength, seed):
    rng = np.random.default_rng(seed)
    real = inject.simulate_sessions(DESIGN, 4, rng, effect, strength)
    sim = inject.simulate_sessions(DESIGN, 4, rng)
    return diagnose("observer", real, sim, DESIGN, seed=seed, n_boot=400)


def _humanlike(n, seed):
    rng = np.random.default_rng(seed)
    obs = [make_observer("humanlike", f"P{i:02d}", rng, design=DESIGN) for i in range(n)]
    return simulate_dataset(DESIGN, obs, rng)


@pytest.mark.parametrize("effect,strength", [("crosstalk", 0.3), ("central_tendency", 0.3),
                                             ("illumination_gain", 0.3), ("lapses", 0.15),
                                             ("label_rounding", 0.4),
                                             ("serial_dependence", 0.3)])
def test_injected_effect_is_top_ranked(effect, strength):
    diag, local = _diag(effect, strength, 3)
    assert diag.steps and diag.steps[0]["added"] == effect
    assert diag.shrink_abs > 0
    assert not diag.unexplained_remains
    assert set(local["response"]) == {"gloss", "depth"}


def test_crosstalk_slope_recovered():
    diag, _ = _diag("crosstalk", 0.3, 5)
    assert diag.steps[0]["params"]["c"] == pytest.approx(0.3, abs=0.05)


def test_nothing_injected_is_no_gap_that_matters():
    diag, _ = _diag("none", 0.0, 11)
    assert diag.verdict == "no_gap_that_matters" and not diag.steps
    assert not diag.unexplained_remains
    assert diag.summary.startswith("No gap that matters")
    assert diag.misfit_upper < diag.tolerance
    assert diag.to_dict()["verdict"] == "no_gap_that_matters"


def test_out_of_catalogue_is_unexplained():
    diag, _ = _diag("stimulus_bias", 0.3, 13)
    assert diag.verdict == "unexplained"
    assert diag.unexplained_remains


def test_effect_outside_the_catalogue_on_top_of_catalogue_effects_is_a_remaining_gap():
    """Human-like observers (compression, crosstalk) from a generator written apart from the
    experiment's, with a gloss x depth interaction on top: the catalogue effects are named,
    and the interaction is reported as a gap that remains, with where it lies."""
    case = HarderCase("out", base=True, added={"interaction": 0.06})
    frame, _ = generate_sessions(DESIGN, case, 4, np.random.default_rng(5))
    ideal = base_from_params(load_observer_params()["ideal"], "ideal", DESIGN.slider)
    diag, _ = diagnose("observer", frame, ideal, DESIGN, seed=1, n_boot=500)
    assert {s["added"] for s in diag.steps} == {"central_tendency", "crosstalk"}
    assert diag.remaining["significant"] and diag.unexplained_remains
    assert diag.remaining["where"] == "in the gloss response, rising with gloss x depth"
    assert "a further gap remains, unexplained by the catalogue, in the gloss response" in (
        diag.summary)
    assert 0.0 <= diag.explained_share <= 1.0


def test_catalogue_effects_alone_leave_no_remaining_gap():
    case = HarderCase("base", base=True)
    frame, _ = generate_sessions(DESIGN, case, 4, np.random.default_rng(6))
    ideal = base_from_params(load_observer_params()["ideal"], "ideal", DESIGN.slider)
    diag, _ = diagnose("observer", frame, ideal, DESIGN, seed=2, n_boot=500)
    assert {s["added"] for s in diag.steps} == {"central_tendency", "crosstalk"}
    assert not diag.remaining["significant"]


@pytest.mark.slow
def test_humanlike_verdict_is_the_same_for_any_seed():
    """The experiment's humanlike observers against the ideal table: compression and crosstalk
    (8 %/cm) for every seed (once central tendency alone on seed 0)."""
    real = _humanlike(2, 7)
    verdicts = {diagnose("observer", real, TOML, DESIGN, seed=s, n_boot=1000,
                         sim_kind="ideal")[0].verdict for s in (0, 1, 2)}
    assert len(verdicts) == 1
    assert set(verdicts.pop().split(" + ")) == {"central_tendency", "crosstalk"}


def test_humanlike_sessions_match_the_humanlike_table():
    """Base = the fitted (here: the shipped humanlike) observer; nothing to attribute."""
    diag, _ = diagnose("observer", _humanlike(4, 8), TOML, DESIGN, seed=0, n_boot=500)
    assert not diag.steps and not diag.unexplained_remains
    assert diag.loss_info["base"]["kind"] == "humanlike"


def test_base_from_the_table_equals_the_experiments_population_observer():
    """Reference: experiment.Observer.estimate + to_slider at the table's population means and
    no noise (the experiment's own code), against the diagnosis's slider-unit base."""
    from experiment import Observer

    table = load_observer_params()["humanlike"]
    means = {k: (v["mean"] if isinstance(v, dict) else v) for k, v in table.items()}
    means |= {"depth_noise_cm": 0.0, "gloss_noise_pct": 0.0}
    obs = Observer("humanlike", "R1", means, DESIGN.slider)
    g = np.array([20.0, 50.0, 80.0, 30.0])
    d = np.array([1.2, 2.4, 3.6, 3.2])
    eg, ed = obs.estimate(g, d, np.random.default_rng(0))
    ref_g, ref_d = obs.to_slider(eg, ed)
    base = base_from_params(table, "humanlike", DESIGN.slider)
    gu, du = to_slider_units(DESIGN.slider, g, d)
    mu = base.mean(gu, du, 0.5 * (DESIGN.slider.min + DESIGN.slider.max))
    assert mu["gloss"] == pytest.approx(ref_g, abs=1e-9)
    assert mu["depth"] == pytest.approx(ref_d, abs=1e-9)


@pytest.mark.parametrize("lo,hi", [(1.0, 11.0), (0.0, 10.0), (2.5, 9.0)])
def test_slider_units_invert_the_designs_slider(lo, hi):
    s = replace(DESIGN.slider, min=lo, max=hi)
    v = np.linspace(lo, hi, 7)
    gu, du = to_slider_units(s, s.to_gloss_pct(v), s.to_depth_cm(v))
    assert gu == pytest.approx(v) and du == pytest.approx(v)


def test_sim_that_does_not_match_the_real_data_is_warned_about():
    rng = np.random.default_rng(4)
    real = inject.simulate_sessions(DESIGN, 2, rng)
    other = real.copy()
    other["participant"] = other["participant"].str.replace("B", "Z")
    diag, _ = diagnose("observer", real, other, DESIGN, seed=0, n_boot=200)
    assert any("not the real ones" in w for w in diag.warnings)
    assert any("ideal observer" in w for w in diag.warnings)
    diag, _ = diagnose("observer", real, TOML, DESIGN, seed=0, n_boot=200, sim_kind="ideal")
    assert any("fit-observer" in w for w in diag.warnings)


def test_holm_reference():
    # Worked example: p = (0.01, 0.04, 0.03) -> Holm (0.03, 0.06, 0.06).
    assert holm(np.array([0.01, 0.04, 0.03])) == pytest.approx([0.03, 0.06, 0.06])


def test_diagnosis_never_imports_injectors():
    """Blindness: no diagnosis module imports the injectors, the benchmarks or their
    generators (only the benchmark modules do)."""
    for path in GAP_DIR.glob("*.py"):
        # The CLI (__main__) may start the benchmark; the diagnosis modules may not.
        if path.name in ("benchmark.py", "inject.py", "__main__.py") or path.name.startswith(
                "bench_"):
            continue
        tree = ast.parse(path.read_text())
        names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        names += [f"{n.module}.{a.name}" for n in ast.walk(tree)
                  if isinstance(n, ast.ImportFrom) for a in n.names]
        assert not any("inject" in n or "bench" in n for n in names), path
        # Nor the simulators the injectors generate pseudo-real data with.
        assert not any(n.endswith(("SimulatedCRT", "load_crt", "make_observer", "simulate_dataset",
                                   "write_simulated_sessions", "make_plan")) for n in names), path


def test_cli_diagnose_writes_report_and_refuses_overwrite(tmp_path, capsys):
    rng = np.random.default_rng(2)
    real = inject.simulate_sessions(DESIGN, 2, rng, "crosstalk", 0.3)
    real["illumination"] = real["illumination"].map({"indoor": "lab_A", "outdoor": "lab_B"})
    real["stimulus_id"] = [f"photo{i:04d}" for i in range(len(real))]
    inject.write_sessions(real, tmp_path / "real")
    inject.write_sessions(inject.simulate_sessions(DESIGN, 2, rng), tmp_path / "sim")
    args = ["diagnose", "--layer", "observer", "--real", str(tmp_path / "real"),
            "--sim", str(tmp_path / "sim"), "--out", str(tmp_path / "rep")]
    assert main(args) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    assert "crosstalk" in page and "localisation.png" in page
    # Written with the umask's permissions (a temporary file's 0600 once leaked through).
    assert stat.S_IMODE((tmp_path / "rep" / "index.html").stat().st_mode) & 0o044
    assert main(args) == 2
    assert "exists" in capsys.readouterr().err


def test_cli_diagnose_accepts_an_observers_toml(tmp_path, capsys):
    inject.write_sessions(_humanlike(2, 9), tmp_path / "real")
    assert main(["diagnose", "--layer", "observer", "--real", str(tmp_path / "real"),
                 "--sim", str(TOML), "--sim-kind", "ideal", "--out",
                 str(tmp_path / "rep")]) == 0
    out = capsys.readouterr()
    assert "crosstalk" in out.out and "fit-observer" in out.err


def test_bad_input(tmp_path):
    from analysis.gap import read_session_csvs

    (tmp_path / "x.csv").write_text("a,b\n1,2\n")
    with pytest.raises(GapError, match="columns"):
        read_session_csvs(tmp_path)
    (tmp_path / "empty").mkdir()
    with pytest.raises(GapError, match="no session CSVs"):
        read_session_csvs(tmp_path / "empty")
    with pytest.raises(GapError, match="no \\[humanlike\\] table|lacks the tables"):
        (tmp_path / "obs.toml").write_text("[ideal]\nx = 1\n")
        diagnose("observer", _humanlike(1, 1), tmp_path / "obs.toml", DESIGN, seed=0)
    with pytest.raises(GapError, match="unknown layer"):
        diagnose("optics", tmp_path, tmp_path, DESIGN, seed=0)


def _diagnosis(**kw):
    from analysis.gap.engine import Diagnosis

    base = {"layer": "display", "ranking": (), "steps": (), "verdict": "unexplained",
            "gap_before": 0.3, "gap_after": 0.3, "shrink_abs": 0.0, "shrink_abs_ci": (0.0, 0.0),
            "shrink_pct": 0.0, "shrink_pct_ci": (0.0, 0.0), "seed": 1}
    return Diagnosis(**(base | kw))


def test_a_gap_ci_reaching_zero_without_a_bound_is_inconclusive_never_no_gap():
    """Issue 43: "no significant gap" is no longer a verdict. Without a ceiling or a bound on
    the misfit in the lab's units nothing is excluded: inconclusive (amber badge), and the
    words never say "no gap"."""
    from analysis.gap.engine import summarise
    from analysis.gap.report import badge, outcome, verdict_text

    none = _diagnosis(gap_before_ci=(-0.09, 0.88), verdict="inconclusive")
    none = replace(none, summary=summarise(none))
    some = _diagnosis(gap_before_ci=(0.2, 0.9))
    some = replace(some, summary=summarise(some))
    assert outcome(none) == "inconclusive" and 'class="badge inconclusive"' in badge(none)
    assert verdict_text(none).startswith("<p>Inconclusive:"), verdict_text(none)
    assert "no significant gap" not in verdict_text(none).lower()
    assert outcome(some) == "gap" and "unexplained" in verdict_text(some)
    assert 'class="badge gap"' in badge(some)
    below = _diagnosis(gap_before=-0.26, gap_before_ci=(-0.29, -0.23), floor_status="misestimated")
    below = replace(below, summary=summarise(below))
    below = replace(below, verdict="inconclusive")
    below = replace(below, summary=summarise(below))
    assert outcome(below) == "inconclusive"
    assert "mis-estimated" in verdict_text(below)


def _pilot_fit(design):
    """The observer fitted to a pilot of four humanlike observers (the demo's step). Until
    experiment.fit_observer_params is merged, the table the pilot was drawn from stands in for
    the fit (a perfect fit)."""
    import experiment

    rng = np.random.default_rng(2)
    pilot = simulate_dataset(design, [make_observer("humanlike", f"PILOT{i}", rng, design=design)
                                      for i in range(1, 5)], rng)
    fit = getattr(experiment, "fit_observer_params", None)
    if fit is None:
        return load_observer_params()
    return fit(pilot, design)


@pytest.mark.slow
def test_demo_gap_step_verdicts_are_right_for_any_seed(tmp_path):
    """The demo's observer step: two humanlike participants (the app's D01, D02) against the
    observer fitted to a pilot (no significant gap) and against the ideal observer's sessions
    (central tendency + crosstalk, the humanlike observer's known effects), seeds 0, 1, 2."""
    rng = np.random.default_rng(1)
    real = simulate_dataset(DESIGN, [make_observer("humanlike", p, rng, design=DESIGN)
                                     for p in ("D01", "D02")], rng)
    ideal = simulate_dataset(DESIGN, [make_observer("ideal", p, rng, design=DESIGN)
                                      for p in ("D01", "D02")], rng)
    table = _pilot_fit(DESIGN)
    fitted = base_from_params(table["humanlike"], "fitted" if "fit" in table else "humanlike",
                              DESIGN.slider, fit_info=table.get("fit"))
    for seed in (0, 1, 2):
        d_fit, _ = diagnose("observer", real, fitted, DESIGN, seed=seed, n_boot=1000)
        assert not d_fit.steps and not d_fit.unexplained_remains, d_fit.summary
        d_ideal, _ = diagnose("observer", real, ideal, DESIGN, seed=seed, n_boot=1000)
        assert set(d_ideal.verdict.split(" + ")) == {"central_tendency", "crosstalk"}


def test_demo_sessions_against_the_ideal_observer_leave_individual_differences(repo_root):
    """The demo's own humanlike sessions (tests/data/demo_sessions: the app's D01, D02)
    against the ideal observer's: central tendency + crosstalk, and a remaining gap where the
    humanlike observers differ from each other (their own intercepts and slopes, which the
    ideal observer lacks): 0.043 nats per trial (95 % CI 0.012-0.077) at commit 7006fc6,
    0.039 with the cell offsets' lapse weights and levels kept apart. A change of the observer
    ceiling that left 0.030 'in the gloss response, varying from stimulus to stimulus',
    flagged on some seeds only, was reverted for failing this."""
    folder = repo_root / "tests" / "data" / "demo_sessions"
    diag, _ = diagnose("observer", folder / "humanlike", folder / "ideal", DESIGN, seed=0,
                       n_boot=1000)
    assert set(diag.verdict.split(" + ")) == {"central_tendency", "crosstalk"}
    assert diag.remaining["significant"] and diag.remaining["gap"] > 0.035
    assert "differing between participants" in diag.remaining["where"]


def test_fitted_observer_allows_each_participant_its_own_departure():
    """Folds by trial (two participants): a participant whose own slopes lie within the table's
    between-observer SDs is no gap against that table, while the ideal table (no SDs) keeps the
    plain population base."""
    from analysis.gap.observer import adapt_base, observer_folds, observer_frame

    table = load_observer_params()["humanlike"]
    base = base_from_params(table, "humanlike", DESIGN.slider)
    assert base.sd["gloss"][0] > 0 and base.sd["depth"][1] == pytest.approx(0.08)
    data = observer_frame(_humanlike(2, 3), DESIGN, base)
    (tr, te), *_ = observer_folds(data)[0]
    before = te["gloss_base"].to_numpy().copy()
    adapt_base(tr, te, base)
    own = te["gloss_match"].to_numpy()
    assert np.mean((own - te["gloss_base"]) ** 2) < np.mean((own - before) ** 2)
    ideal = base_from_params(load_observer_params()["ideal"], "ideal", DESIGN.slider)
    data = observer_frame(_humanlike(2, 3), DESIGN, ideal)
    (tr, te), *_ = observer_folds(data)[0]
    before = te["gloss_base"].to_numpy().copy()
    adapt_base(tr, te, ideal)
    assert te["gloss_base"].to_numpy() == pytest.approx(before)
