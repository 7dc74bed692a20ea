"""Fitting the simulated observers to session data: parameter recovery, bad input, the command."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pandas as pd
import pytest

import experiment
from experiment import (
    SESSION_COLUMNS,
    ObserverFitError,
    fit_observer_params,
    load_observer_params,
    make_observer,
    simulate_dataset,
    write_observer_params,
)
from experiment.__main__ import main
from experiment.observer_fit import HUMANLIKE_PARAMS, ObserverFitWarning

#: Known population of the recovery tests: the shipped humanlike table (fixed numbers have sd 0).
SHIPPED = load_observer_params()["humanlike"]


def _truth(table) -> dict:
    return {k: (dict(v) if isinstance(v, dict) else {"mean": float(v), "sd": 0.0})
            for k, v in table.items()}


def _misses(params: dict, truth: dict, z: float = 4.0) -> list[str]:
    """Parameters whose fitted mean or sd is more than ``z`` of its own SE from the truth."""
    se = params["fit"]["standard_errors"]["humanlike"]
    out = []
    for name in HUMANLIKE_PARAMS:
        for part in ("mean", "sd"):
            err = params["humanlike"][name][part] - truth[name][part]
            if not abs(err) <= z * se[name][part]:
                out.append(f"{name}.{part}: fitted {params['humanlike'][name][part]:.4g}, true "
                           f"{truth[name][part]:.4g}, SE {se[name][part]:.3g}")
    return out


def _simulated(design, n: int, seed: int, table=SHIPPED) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    obs = [make_observer("humanlike", f"R{k:02d}", rng, table, design=design) for k in range(n)]
    return simulate_dataset(design, obs, rng)


# ------------------------------------------------------------------------- parameter recovery
def test_fit_recovers_humanlike_population_from_11_simulated_observers(design):
    frame = _simulated(design, 11, seed=11)
    assert len(frame) == 11 * design.n_stimuli == 11 * 162
    params = fit_observer_params(frame, design)
    assert _misses(params, _truth(SHIPPED)) == []
    assert params["fit"]["n_participants"] == 11
    assert params["fit"]["n_trials"] == 1782
    assert len(params["fit"]["sessions"]) == 22
    # The population is really spread: the SDs of the random slopes are found, not zero.
    for name in ("depth_slope", "gloss_intercept_pct", "crosstalk_pct_per_cm", "rt_median_s"):
        assert params["humanlike"][name]["sd"] > 0.4 * SHIPPED[name]["sd"], name


def test_fit_is_more_precise_with_40_observers(design):
    small = fit_observer_params(_simulated(design, 11, seed=3), design)
    large = fit_observer_params(_simulated(design, 40, seed=4), design)
    assert _misses(large, _truth(SHIPPED)) == []
    se_s = small["fit"]["standard_errors"]["humanlike"]
    se_l = large["fit"]["standard_errors"]["humanlike"]
    # SEs of the means shrink about as 1 / sqrt(n participants): sqrt(40 / 11) = 1.9 (each SE
    # is itself estimated from 11 or 40 observers, hence the range).
    ratios = [se_s[k]["mean"] / se_l[k]["mean"] for k in HUMANLIKE_PARAMS]
    assert 1.5 < np.median(ratios) < 2.5, dict(zip(HUMANLIKE_PARAMS, np.round(ratios, 2)))
    assert min(ratios) > 1.1, dict(zip(HUMANLIKE_PARAMS, np.round(ratios, 2)))


def test_fit_agrees_with_statsmodels_mixedlm_where_nothing_is_censored(design):
    """Reference: statsmodels' MixedLM (REML; independent random intercept and slope per
    participant, one residual SD) on the depth answers, which the shipped observer almost never
    puts at a slider end. The two-stage fit must give the same population means, SDs and SEs."""
    import statsmodels.formula.api as smf

    frame = _simulated(design, 11, seed=21)
    depth_cm = design.slider.to_depth_cm(frame["depth_match"])
    assert ((frame["depth_match"] <= 1) | (frame["depth_match"] >= 11)).sum() <= 3
    mid = design.slider.to_depth_cm(0.5 * (design.slider.min + design.slider.max))
    data = frame.assign(x=frame["true_depth_cm"] - mid, y=depth_cm - mid)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = smf.mixedlm("y ~ x", data, groups="participant", re_formula="1",
                          vc_formula={"slope": "0 + x"}).fit(reml=True)
    params = fit_observer_params(frame, design)
    fitted, se = params["humanlike"], params["fit"]["standard_errors"]["humanlike"]
    pairs = {"depth_intercept_cm": (ref.fe_params["Intercept"], ref.bse_fe["Intercept"],
                                    float(np.sqrt(ref.cov_re.iloc[0, 0]))),
             "depth_slope": (ref.fe_params["x"], ref.bse_fe["x"], float(np.sqrt(ref.vcomp[0])))}
    for name, (mean, se_mean, sd) in pairs.items():
        assert fitted[name]["mean"] == pytest.approx(mean, abs=0.1 * se[name]["mean"]), name
        assert se[name]["mean"] == pytest.approx(se_mean, rel=0.05), name
        assert fitted[name]["sd"] == pytest.approx(sd, abs=0.1 * se[name]["sd"]), name
    assert fitted["depth_noise_cm"]["mean"] == pytest.approx(np.sqrt(ref.scale), rel=0.01)


def _numpy_observers(n: int, rng: np.random.Generator, pop: dict, *, gloss_levels_pct,
                     depth_levels_cm, repeats: int = 2) -> pd.DataFrame:
    """The humanlike equations written out here with numpy alone (no experiment code).

    The slider is the shipped design's, typed in by hand: v_gloss = 1 + gloss_pct / 10,
    v_depth = depth_cm / 0.4, clipped to [1, 11]; its middle (v = 6) is 50 % and 2.4 cm.
    Every observer answers each gloss x depth cell ``repeats`` times (two illuminations).
    """
    g, d = np.meshgrid(gloss_levels_pct, depth_levels_cm, indexing="ij")
    g = np.tile(g.ravel(), repeats)
    d = np.tile(d.ravel(), repeats)
    rows = []
    for k in range(n):
        p = {name: rng.normal(v["mean"], v["sd"]) for name, v in pop.items()}
        depth_hat = (2.4 + p["depth_slope"] * (d - 2.4) + p["depth_intercept_cm"]
                     + rng.normal(0, p["depth_noise_cm"], d.size))
        gloss_hat = (50 + p["gloss_slope"] * (g - 50) + p["crosstalk_pct_per_cm"] * (d - 2.4)
                     + p["interaction_per_cm"] * (g - 50) * (d - 2.4) + p["gloss_intercept_pct"]
                     + rng.normal(0, p["gloss_noise_pct"], g.size))
        rt = p["rt_median_s"] * np.exp(rng.normal(0, p["rt_log_sd"], g.size))
        order = rng.permutation(g.size)
        half = g.size // 2
        rows.append(pd.DataFrame({
            "participant": f"N{k:02d}", "session": np.where(np.arange(g.size) < half, 1, 2),
            "trial": np.arange(g.size) % half + 1, "order": order,
            "stimulus_id": [f"s{i}" for i in order],
            "illumination": "lab", "gloss_level": g[order] / 10 + 1,
            "depth_level": d[order] / 0.4, "true_gloss_pct": g[order],
            "true_depth_cm": d[order],
            "gloss_match": np.clip(1 + gloss_hat[order] / 10, 1, 11),
            "depth_match": np.clip(depth_hat[order] / 0.4, 1, 11), "rt_s": rt,
            "onset_s": np.arange(g.size) * 6.0, "dropped_frames": 0,
            "timestamp_utc": "2026-11-23T10:00:00.000000Z", "app_version": "0.1.0",
            "calibration_id": "lab-crt"}))
    return pd.concat(rows, ignore_index=True)[list(SESSION_COLUMNS)]


def test_fit_recovers_an_observer_written_apart_from_the_simulator(design, rng):
    assert (design.slider.min, design.slider.max) == (1.0, 11.0)
    assert design.slider.to_gloss_pct(6.0) == pytest.approx(50.0)
    assert design.slider.to_depth_cm(6.0) == pytest.approx(2.4)
    pop = {"depth_slope": {"mean": 0.7, "sd": 0.1}, "depth_intercept_cm": {"mean": 0.2, "sd": 0.15},
           "depth_noise_cm": {"mean": 0.4, "sd": 0.05}, "gloss_slope": {"mean": 0.8, "sd": 0.1},
           "gloss_intercept_pct": {"mean": -5.0, "sd": 3.0},
           "crosstalk_pct_per_cm": {"mean": 5.0, "sd": 1.5},
           "interaction_per_cm": {"mean": 0.03, "sd": 0.0},
           "gloss_noise_pct": {"mean": 8.0, "sd": 1.0}, "rt_median_s": {"mean": 3.0, "sd": 0.5},
           "rt_log_sd": {"mean": 0.35, "sd": 0.05}}
    frame = _numpy_observers(16, rng, pop, gloss_levels_pct=np.arange(10, 100, 10),
                             depth_levels_cm=np.arange(2, 11) * 0.4)
    params = fit_observer_params(frame, design)
    assert _misses(params, pop) == []


def test_answers_at_the_slider_ends_are_fitted_as_censored(design, rng):
    """Steep, noisy gloss answers pile up at the ends: the censored fit still finds the slope,
    a least-squares line through the clipped answers does not (so this test can fail)."""
    pop = _truth(SHIPPED)
    pop["gloss_slope"] = {"mean": 1.4, "sd": 0.05}
    pop["gloss_noise_pct"] = {"mean": 15.0, "sd": 0.0}
    frame = _numpy_observers(12, rng, pop, gloss_levels_pct=np.arange(0, 110, 10),
                             depth_levels_cm=np.arange(1, 12) * 0.4)
    params = fit_observer_params(frame, design)
    at_end = params["fit"]["n_censored"]["gloss"] / len(frame)
    assert at_end > 0.2
    assert _misses(params, pop) == []
    se = params["fit"]["standard_errors"]["humanlike"]["gloss_slope"]["mean"]
    ols = np.mean([np.polyfit(r["true_gloss_pct"], design.slider.to_gloss_pct(r["gloss_match"]),
                              1)[0] for _, r in frame.groupby("participant")])
    assert 1.4 - ols > 4 * se


# --------------------------------------------------------------------------- the file format
def test_fitted_params_round_trip_through_toml_and_drive_the_simulator(tmp_path, design):
    params = fit_observer_params(_simulated(design, 3, seed=5), design)
    path = write_observer_params(tmp_path / "observers.toml", params)
    assert load_observer_params(path) == params
    assert set(params) == {"ideal", "humanlike", "fit"}
    obs = make_observer("humanlike", "P01", np.random.default_rng(0),
                        load_observer_params(path)["humanlike"], design=design)
    assert obs.params["depth_slope"] != SHIPPED["depth_slope"]["mean"]
    make_observer("ideal", "P01", np.random.default_rng(0), params["ideal"], design=design)
    with pytest.raises(FileExistsError):
        write_observer_params(path, params)
    write_observer_params(path, params, overwrite=True)
    assert load_observer_params(path) == params


@pytest.mark.parametrize("text, match", [
    ("depth_slope = [", "not valid TOML"),
    ("[ideal]\ndepth_noise_cm = 0.3\n[humanlike]\n", "lacks"),
    ("[humanlike]\n", "lacks the tables"),
])
def test_bad_observer_file_gets_a_clear_error(tmp_path, text, match):
    path = tmp_path / "observers.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        load_observer_params(path)
    with pytest.raises(ValueError, match="does not exist"):
        load_observer_params(tmp_path / "absent.toml")


# --------------------------------------------------------------------------------- bad input
def test_bad_session_data_is_refused_with_the_fix(design):
    frame = _simulated(design, 2, seed=6)
    cases = [
        (frame.iloc[:0], "no session rows"),
        (frame.drop(columns="rt_s"), "lack the columns"),
        (frame[frame["participant"] == "R00"], "only one participant"),
        (frame.assign(depth_match=frame["depth_match"] + 20), "outside the slider's range"),
        (frame.assign(gloss_match=np.nan), "non-numeric"),
        (pd.concat([frame, frame.iloc[:5].assign(participant="X")]), "fewer than 20"),
        (frame.assign(rt_s=0.0), "rt_s <= 0"),
        (frame.assign(gloss_match=np.where(frame["participant"] == "R01", 6.0,
                                           frame["gloss_match"])), "no trial-to-trial spread"),
        (frame.assign(depth_match=np.where(frame["participant"] == "R01", 11.0,
                                           frame["depth_match"])), "at its ends"),
    ]
    for bad, match in cases:
        with pytest.raises(ObserverFitError, match=match):
            fit_observer_params(bad, design)
    with pytest.raises(ValueError, match="unknown observer kind"):
        fit_observer_params(frame, design, kind="average")


def test_simulated_rows_mixed_with_real_ones_are_listed(design, rng):
    real = _numpy_observers(2, rng, _truth(SHIPPED), gloss_levels_pct=np.arange(10, 100, 10),
                            depth_levels_cm=np.arange(2, 11) * 0.4)
    mixed = pd.concat([real, _simulated(design, 1, seed=7)], ignore_index=True)
    with pytest.warns(ObserverFitWarning, match=r"simulated observer.*\('R00', 1\)"):
        params = fit_observer_params(mixed, design)
    assert params["fit"]["simulated_sessions"] == ["R00_s1", "R00_s2"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert fit_observer_params(real, design)["fit"]["simulated_sessions"] == []


# ------------------------------------------------------------------------------- the command
def _write_sessions(folder, frame):
    (folder / "sessions").mkdir(parents=True)
    for (who, s), rows in frame.groupby(["participant", "session"]):
        rows.to_csv(folder / "sessions" / f"{who}_s{s}.csv", index=False)


def test_fit_observer_command_writes_a_file_simulate_accepts(tmp_path, design, rng, capsys):
    real = _numpy_observers(4, rng, _truth(SHIPPED), gloss_levels_pct=np.arange(10, 100, 10),
                            depth_levels_cm=np.arange(2, 11) * 0.4)
    _write_sessions(tmp_path / "data", real)
    out = tmp_path / "observers.toml"
    assert main(["fit-observer", str(tmp_path / "data"), "--out", str(out)]) == 0
    report = capsys.readouterr().out
    assert "fitted 4 participants, 648 trials from 8 files" in report
    assert "crosstalk_pct_per_cm" in report
    fitted = load_observer_params(out)
    assert fitted["fit"]["participants"] == ["N00", "N01", "N02", "N03"]
    before = out.read_bytes()
    assert main(["fit-observer", str(tmp_path / "data"), "--out", str(out)]) == 1
    assert "never overwritten" in capsys.readouterr().err
    assert out.read_bytes() == before
    assert main(["simulate", "--observer", "humanlike", "--participants", "S01", "--data",
                 str(tmp_path / "sim"), "--observer-params", str(out)]) == 0
    assert len(experiment.read_session(tmp_path / "sim" / "sessions" / "S01_s1.csv")) == 81


def test_fit_observer_command_refuses_bad_input(tmp_path, design, rng, capsys):
    (tmp_path / "empty").mkdir()
    out = str(tmp_path / "o.toml")
    assert main(["fit-observer", str(tmp_path / "empty"), "--out", out]) == 2
    assert "holds no session CSVs" in capsys.readouterr().err
    one = _numpy_observers(1, rng, _truth(SHIPPED), gloss_levels_pct=np.arange(10, 100, 10),
                           depth_levels_cm=np.arange(2, 11) * 0.4)
    _write_sessions(tmp_path / "one", one)
    assert main(["fit-observer", str(tmp_path / "one"), "--out", out]) == 2
    assert "at least 2 participants" in capsys.readouterr().err
    (tmp_path / "notes.txt").write_text("x")
    assert main(["fit-observer", str(tmp_path / "notes.txt"), "--out", out]) == 2
    assert "not a session CSV" in capsys.readouterr().err
    assert not (tmp_path / "o.toml").exists()


def test_fit_observer_command_lists_sessions_the_app_ran_simulated(tmp_path, rng, capsys):
    real = _numpy_observers(3, rng, _truth(SHIPPED), gloss_levels_pct=np.arange(10, 100, 10),
                            depth_levels_cm=np.arange(2, 11) * 0.4)
    _write_sessions(tmp_path / "data", real)
    (tmp_path / "data" / "logs").mkdir()
    (tmp_path / "data" / "logs" / "N01_s2_run1.json").write_text(
        json.dumps({"simulated": {"observer": {"kind": "humanlike"}}}))
    out = tmp_path / "o.toml"
    assert main(["fit-observer", str(tmp_path / "data"), "--out", str(out)]) == 0
    assert "warning:" in capsys.readouterr().err
    assert load_observer_params(out)["fit"]["simulated_sessions"] == ["N01_s2"]


@pytest.mark.parametrize("extra, match", [
    (["--simulate", "humanlike"], "not valid TOML"),
    ([], "add --simulate"),
])
def test_run_refuses_a_bad_observer_file_before_starting(tmp_path, extra, match, capsys):
    bad = tmp_path / "observers.toml"
    bad.write_text("this is not toml [")
    code = main(["run", "--participant", "P01", "--session", "1", "--stimuli",
                 str(tmp_path / "manifest.csv"), "--calibration", str(tmp_path / "cal.json"),
                 "--data", str(tmp_path / "data"), "--observer-params", str(bad), *extra])
    assert code == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "data").exists()


def test_simulate_refuses_a_bad_observer_file(tmp_path, capsys):
    bad = tmp_path / "observers.toml"
    bad.write_text("[ideal]\n")
    assert main(["simulate", "--observer", "ideal", "--participants", "S01", "--data",
                 str(tmp_path / "sim"), "--observer-params", str(bad)]) == 2
    assert "lacks the tables" in capsys.readouterr().err
    assert not (tmp_path / "sim").exists()


@pytest.mark.parametrize("line, said", [
    ("gloss_noise_pct = { mean = nan, sd = 1.0 }", "humanlike.gloss_noise_pct.mean = nan"),
    ("gloss_noise_pct = inf", "humanlike.gloss_noise_pct = inf"),
    ("gloss_noise_pct = { mean = 10.0, sd = -inf }", "humanlike.gloss_noise_pct.sd = -inf"),
])
def test_non_finite_observer_parameters_are_refused_before_anything_is_written(
        tmp_path, capsys, line, said):
    """Issue 40, item 7: ``nan`` in observers.toml made ``simulate`` write every gloss match as
    nan (exit 0), ``gap diagnose`` die in scipy and ``run`` open the window and die at trial 1.
    Each reader of the file now refuses it, naming the key, before any file or window."""
    from analysis.gap.__main__ import main as gap_main
    from experiment.observers import default_observers_path

    shipped = default_observers_path().read_text(encoding="utf-8")
    assert shipped.count("gloss_noise_pct = 10.0") == 1
    bad = tmp_path / "observers.toml"
    bad.write_text(shipped.replace("gloss_noise_pct = 10.0", line), encoding="utf-8")
    fix = "write a number there (see experiment/observers.toml)"
    assert main(["simulate", "--observer", "humanlike", "--participants", "S01", "--data",
                 str(tmp_path / "sim"), "--observer-params", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: {said} is not a finite number" in err and fix in err
    assert not (tmp_path / "sim").exists()
    code = main(["run", "--participant", "P01", "--session", "1", "--stimuli",
                 str(tmp_path / "manifest.csv"), "--calibration", str(tmp_path / "cal.json"),
                 "--data", str(tmp_path / "data"), "--simulate", "humanlike", "--fast",
                 "--observer-params", str(bad)])
    assert code == 2 and said in capsys.readouterr().err
    assert not (tmp_path / "data").exists()
    assert main(["simulate", "--observer", "humanlike", "--participants", "S01", "--data",
                 str(tmp_path / "real")]) == 0
    capsys.readouterr()
    assert gap_main(["diagnose", "--layer", "observer", "--real", str(tmp_path / "real"),
                     "--sim", str(bad), "--out", str(tmp_path / "rep")]) == 2
    assert said in capsys.readouterr().err
    assert not any((tmp_path / "rep").glob("*"))  # gap makes --out first, writes nothing


@pytest.mark.xvfb
@pytest.mark.slow
def test_run_simulate_uses_a_fitted_observer_file(tmp_path, session_files, design):
    """The app's simulated participant takes its parameters from a fitted file (SDs of 0 make
    the drawn observer equal to the file's means)."""
    from .conftest import run_app

    params = fit_observer_params(_simulated(design, 3, seed=8), design)
    for value in params["humanlike"].values():
        value["sd"] = 0.0
    path = write_observer_params(tmp_path / "fitted.toml", params)
    f = session_files
    res = run_app("run", "--participant", "P07", "--session", "1", "--stimuli", f["manifest"],
                  "--calibration", f["calibration"], "--data", f["data"], "--simulate",
                  "humanlike", "--fast", "--simulate-quit-at", "3", "--observer-params", path)
    assert res.returncode == 3, res.stderr
    log = json.loads((f["data"] / "logs" / "P07_s1_run1.json").read_text())
    drawn = log["simulated"]["observer"]["params"]
    assert drawn == {k: pytest.approx(v["mean"]) for k, v in params["humanlike"].items()}
    assert len(experiment.read_session(f["data"] / "sessions" / "P07_s1.csv")) == 2


def test_drawn_noise_is_never_negative(design):
    """A fitted spread may reach below 0: each observer's noise SD is drawn from the normal
    truncated at 0, not refused; a negative mean is refused."""
    table = _truth(SHIPPED)
    table["gloss_noise_pct"] = {"mean": 1.0, "sd": 5.0}
    rng = np.random.default_rng(0)
    noise = [make_observer("humanlike", f"P{k}", rng, table, design=design).params[
        "gloss_noise_pct"] for k in range(200)]
    assert min(noise) >= 0
    assert np.mean(noise) > 1.0  # truncation at 0 raises the mean of the draws
    table["gloss_noise_pct"] = {"mean": -1.0, "sd": 1.0}
    with pytest.raises(ValueError, match="must be >= 0"):
        make_observer("humanlike", "P1", rng, table, design=design)
