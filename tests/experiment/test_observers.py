"""Simulated observers and the session file format (no window)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import analysis.load
import experiment
from analysis.load import load_sessions
from experiment import (
    SESSION_COLUMNS,
    make_observer,
    read_session,
    simulate_dataset,
    write_simulated_sessions,
)


def test_analysis_reads_sessions_with_the_experiments_reader():
    assert analysis.load.read_session is read_session
    assert not hasattr(analysis.load, "SESSION_COLUMNS")  # one column list, the experiment's
    assert SESSION_COLUMNS[:3] == ("participant", "session", "trial")


def test_ideal_observer_recovers_truth_on_average(design, rng):
    obs = make_observer("ideal", "P01", rng)
    plan = experiment.make_plan(design, "P01", rng, seed=0)
    g = np.array([obs.respond(row, rng) for _, row in plan.iterrows()])
    truth_g = plan["gloss_level"].to_numpy(float)  # slider position of the true gloss
    truth_d = plan["depth_level"].to_numpy(float)
    assert np.all((g >= design.slider.min) & (g <= design.slider.max))
    assert np.polyfit(truth_g, g[:, 0], 1)[0] == pytest.approx(1.0, abs=0.1)
    assert np.polyfit(truth_d, g[:, 1], 1)[0] == pytest.approx(1.0, abs=0.1)


def test_humanlike_observer_parameters_recovered(design, rng):
    """Noise-free humanlike answers follow the model's compression and crosstalk exactly."""
    params = dict(experiment.load_observer_params()["humanlike"])
    params.update(depth_noise_cm=0.0, gloss_noise_pct=0.0)
    obs = make_observer("humanlike", "P02", rng, params)
    stim = design.stimuli()
    gloss_v, depth_v = obs.respond_all(stim, rng)
    depth_cm = design.slider.to_depth_cm(depth_v)
    slope = np.polyfit(stim["true_depth_cm"], depth_cm, 1)[0]
    assert slope == pytest.approx(obs.params["depth_slope"], abs=1e-9)
    assert slope < 1
    # No gloss-to-depth effect: depth answers do not change with gloss.
    same_depth = stim.assign(d=depth_cm).groupby("depth_level")["d"].nunique()
    assert (same_depth == 1).all()
    # Deeper looks glossier at the middle gloss.
    mid = stim[(stim["gloss_level"] == 6) & (stim["illumination"] == stim["illumination"][0])]
    assert np.all(np.diff(gloss_v[mid.index][np.argsort(mid["true_depth_cm"])]) > 0)


def test_observers_differ_between_participants(rng):
    a = make_observer("humanlike", "P01", rng)
    b = make_observer("humanlike", "P02", rng)
    assert a.params["depth_slope"] != b.params["depth_slope"]


@pytest.mark.parametrize("kind, params, match", [
    ("average", None, "unknown observer kind"),
    ("humanlike", {"depth_slope": 0.5}, "lack"),
    ("ideal", {"depth_noise_cm": -1, "gloss_noise_pct": 1, "rt_median_s": 3, "rt_log_sd": 0.1},
     ">= 0"),
    ("ideal", {"depth_noise_cm": {"mean": 1}, "gloss_noise_pct": 1, "rt_median_s": 3,
               "rt_log_sd": 0.1}, "sd"),
])
def test_bad_observer_parameters(kind, params, match, rng):
    with pytest.raises(ValueError, match=match):
        make_observer(kind, "P01", rng, params)


def test_bad_participant_id_rejected(rng):
    with pytest.raises(ValueError, match="not valid"):
        make_observer("ideal", "P 01", rng)


def test_simulated_sessions_load_in_analysis(tmp_path, design, rng):
    observers = [make_observer("humanlike", f"S{k}", rng) for k in range(2)]
    paths = write_simulated_sessions(tmp_path, design, observers, rng)
    assert len(paths) == 2 * design.sessions.n_sessions
    data = load_sessions(tmp_path, design)
    assert len(data.warnings) == 1
    assert data.warnings[0].startswith("simulated data included: participants ['S0', 'S1']")
    assert len(data.frame) == 2 * design.n_stimuli
    # Same plans as the app: seeded by the participant id.
    plan = experiment.load_or_create_plan(design, "S0", tmp_path / "plans_dir")
    s1 = read_session(paths[0])
    assert list(s1["stimulus_id"]) == list(plan[plan["session"] == 1]["stimulus_id"])
    with pytest.raises(FileExistsError):
        write_simulated_sessions(tmp_path, design, observers, rng)


def test_simulated_sessions_are_written_by_the_apps_session_writer(tmp_path, design, monkeypatch):
    """Simulated and app sessions have one writer: its rows, fsynced, and no histories file."""

    from experiment import datafile

    calls = []
    real_extend = datafile.SessionWriter.extend

    def extend(self, rows):
        rows = list(rows)
        calls.append((self.path, len(rows)))
        return real_extend(self, rows)

    monkeypatch.setattr(datafile.SessionWriter, "extend", extend)
    obs = [make_observer("ideal", "S0", np.random.default_rng(1), design=design)]
    paths = write_simulated_sessions(tmp_path, design, obs, np.random.default_rng(2))
    assert [c[0] for c in calls] == paths
    assert sum(c[1] for c in calls) == design.n_stimuli
    expected = simulate_dataset(design, obs, np.random.default_rng(2))
    got = pd.concat([read_session(p) for p in paths], ignore_index=True)
    assert got["gloss_match"].to_numpy() == pytest.approx(expected["gloss_match"].to_numpy())
    assert not (tmp_path / "sliders").exists()

def test_simulate_dataset_shape(design, rng):
    obs = [make_observer("ideal", "A", rng), make_observer("ideal", "B", rng)]
    frame = simulate_dataset(design, obs, rng)
    assert tuple(frame.columns) == SESSION_COLUMNS
    assert len(frame) == 2 * design.n_stimuli
    assert frame.groupby("participant")["stimulus_id"].nunique().eq(design.n_stimuli).all()
    assert isinstance(frame, pd.DataFrame)
    with pytest.raises(ValueError, match="repeat"):
        simulate_dataset(design, [obs[0], obs[0]], rng)

def test_simulate_command_writes_and_never_overwrites(tmp_path, design, capsys):
    from experiment.__main__ import main

    args = ["simulate", "--observer", "ideal", "--participants", "S01", "S02", "--data",
            str(tmp_path), "--seed", "3"]
    assert main(args) == 0
    files = sorted(p.name for p in (tmp_path / "sessions").iterdir())
    assert files == ["S01_s1.csv", "S01_s2.csv", "S02_s1.csv", "S02_s2.csv"]
    before = (tmp_path / "sessions" / "S01_s1.csv").read_bytes()
    assert main(args) == 1
    assert "never overwritten" in capsys.readouterr().err
    assert (tmp_path / "sessions" / "S01_s1.csv").read_bytes() == before
