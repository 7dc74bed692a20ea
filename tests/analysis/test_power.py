"""analysis.power / powerplan / `python -m analysis power`: the rejection rate of a null effect
is alpha, power rises with participants, results repeat from the seed, bad input is named."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from analysis.__main__ import main
from analysis.lmm import fit
from analysis.models import SOURCE_STUDY_RHS
from analysis.montecarlo import decision_rates
from analysis.power import (
    ALPHA,
    Effect,
    ModelDraws,
    ObserverDraws,
    PowerError,
    layout_frame,
    observer_params,
    scaled_fixef,
)
from analysis.powerplan import PowerSettings, run_power

from .powerdata import pilot_frame

GLOSS = f"gloss_match_pct ~ {SOURCE_STUDY_RHS}"


@pytest.fixture(scope="module")
def pilot(tmp_path_factory, design):
    folder = tmp_path_factory.mktemp("pilot")
    frame = pilot_frame(folder, design)
    return folder, frame, fit(GLOSS, frame)


def test_a_null_interaction_is_rejected_at_alpha_within_monte_carlo_error(pilot, design):
    """The recovery check: the pilot's model with the gloss x depth interaction set to zero,
    2,000 simulated studies of 6 participants: the Type II Wald test rejects at 5 % (3 Monte-
    Carlo SEs: 0.035 to 0.065). It fails when the effect is left at its fitted size."""
    _, _, gfit = pilot
    beta = scaled_fixef(gfit, [Effect("gloss:depth", scale=0.0)], design)
    draws = ModelDraws(gfit, layout_frame(design, 6), beta, ["gloss:depth"])
    (rate,) = decision_rates(draws, 2000, columns=1, seed=11)
    se = np.sqrt(ALPHA * (1 - ALPHA) / rate.n)
    assert abs(rate.rate - ALPHA) < 3 * se, rate
    full = ModelDraws(gfit, layout_frame(design, 6), gfit.fixef_array(), ["gloss:depth"])
    assert decision_rates(full, 50, columns=1, seed=11)[0].rate > 0.9


def test_power_rises_with_participants_and_the_smallest_n_lies_between(pilot, design):
    _, frame, _ = pilot
    s = PowerSettings(models=("gloss",), terms={"gloss": ["gloss:depth"]},
                      participants=(4, 12, 24), n_sim=200, seed=3,
                      effects=(Effect("gloss:depth", scale=0.25),))
    r = run_power(s, design, data=frame, quiet=True)
    rates = [row["rate"] for row in r["curve"]]
    assert rates[0] < rates[1] < rates[2] and rates[0] < 0.5 and rates[2] > 0.8
    (found,) = r["smallest_n"]
    assert found["participants"] in (12, 24)
    # the same seed gives the same counts
    again = run_power(s, design, data=frame, quiet=True)
    assert [row["hits"] for row in again["curve"]] == [row["hits"] for row in r["curve"]]


def test_an_effect_in_study_units_is_the_coefficient_per_percent_and_cm(pilot, design):
    _, _, gfit = pilot
    sd_g, sd_d = np.std(design.gloss.rendered_pct), np.std(design.depth.rendered_cm)
    beta = scaled_fixef(gfit, [Effect("gloss:depth", value=0.05)], design)
    assert beta[list(gfit.fixef).index("gloss:depth")] == pytest.approx(0.05 * sd_g * sd_d)


def test_observers_simulate_whole_sessions_through_the_plan(design):
    from experiment.observers import load_observer_params

    params = load_observer_params()["humanlike"]
    lay = layout_frame(design, 4, sessions=1, repeats=2)
    assert len(lay) == 4 * 2 * design.sessions.trials_per_session
    draws = ObserverDraws(design, params, lay, GLOSS, ["depth", "gloss:depth"], None)
    out = draws(np.random.default_rng(0), 5)
    assert out.shape == (5, 2) and out[:, 0].all()  # the crosstalk is large
    with pytest.raises(PowerError, match="no 'gloss' effect on depth_match_bc"):
        observer_params(params, "depth_match_bc", [Effect("gloss", value=0.5)])


@pytest.mark.parametrize("argv, match", [
    (["--term", "gloss*depth"], (r"not in model 'gloss'.*terms are \['gloss', 'depth', "
                                r"'gloss:depth'\]")),
    (["--model", "glos"], r"no model 'glos'; the models are \['gloss', 'depth'"),
    (["--formula", "gloss_match_pct ~ gloss + shine + (1 | participant)"], "shine"),
    (["--scale", "illumination=0.5"], "not a term of any model"),
])
def test_a_wrong_term_model_or_formula_is_refused_naming_what_exists(pilot, tmp_path, capsys,
                                                                      argv, match):
    folder, _, _ = pilot
    rc = main(["power", str(folder), "--out", str(tmp_path / "p"), "--n-sim", "2", "--quiet",
               "--participants", "4", *argv])
    err = capsys.readouterr().err
    assert rc == 1 and err.startswith("error: ")
    assert re.search(match, err), err


def test_the_command_writes_json_csv_png_and_never_overwrites(pilot, tmp_path, capsys):
    folder, _, _ = pilot
    out = tmp_path / "power"
    argv = ["power", str(folder), "--out", str(out), "--model", "gloss", "--term",
            "gloss:depth", "--participants", "4:6:2", "--n-sim", "20", "--seed", "5",
            "--scale", "gloss:depth=0.5", "--quiet"]
    assert main(argv) == 0
    result = json.loads((out / "power.json").read_text())
    assert result["settings"]["seed"] == 5 and result["simulate"] == "model"
    assert (out / "power.png").stat().st_size > 0
    assert (out / "power.csv").read_text().count("\n") == 3
    assert "from model" in capsys.readouterr().out
    assert main(argv) == 1
    assert "never overwritten" in capsys.readouterr().err


def test_the_report_shows_a_power_result_and_refuses_a_folder_without_one(pilot, tmp_path):
    folder, _, _ = pilot
    power = tmp_path / "power"
    assert main(["power", str(folder), "--out", str(power), "--model", "gloss", "--term",
                 "gloss:depth", "--participants", "4,8", "--n-sim", "10", "--quiet"]) == 0
    assert main(["report", str(folder), "--out", str(tmp_path / "bad"), "--bootstrap", "0",
                 "--quiet", "--power", str(tmp_path)]) == 1
    assert not (tmp_path / "bad" / "index.html").exists()
    assert main(["report", str(folder), "--out", str(tmp_path / "report"), "--bootstrap", "0",
                 "--quiet", "--power", str(power)]) == 0
    page = (tmp_path / "report" / "index.html").read_text()
    assert "Planning a study: power" in page and "gloss:depth" in page
    assert (tmp_path / "report" / "power-1.png").is_file()
    results = json.loads((tmp_path / "report" / "results.json").read_text())
    assert results["power"][0]["settings"]["participants"] == [4, 8]


@pytest.mark.slow
def test_a_run_on_dask_workers_counts_what_one_process_counts(pilot, tmp_path):
    """`--scheduler` with a real `dask scheduler` and `dask worker` (two threads): the same
    hits per point as in this process, from the same --seed (the chunks' seeds do not depend on
    who runs them)."""
    from tests.dask_processes import dask_processes

    folder, _, _ = pilot
    argv = ["power", str(folder), "--model", "gloss", "--term", "gloss:depth",
            "--participants", "4,6", "--n-sim", "60", "--seed", "9", "--quiet",
            "--scale", "gloss:depth=0.3"]
    assert main([*argv, "--out", str(tmp_path / "here")]) == 0
    with dask_processes(tmp_path / "dask") as dask:
        dask.start_worker(nthreads=2)
        dask.wait_workers(1)
        assert main([*argv, "--out", str(tmp_path / "dask-run"), "--scheduler",
                     dask.address]) == 0, dask.logs()
    here, there = (json.loads((tmp_path / d / "power.json").read_text())["curve"]
                   for d in ("here", "dask-run"))
    assert [r["hits"] for r in here] == [r["hits"] for r in there]
    assert 0 < here[0]["hits"] < 60  # an informative count, not all or none


def test_a_batch_cluster_dry_run_prints_one_worker_process_per_core_and_runs_nothing(tmp_path,
                                                                                    capsys):
    assert main(["power", "--out", str(tmp_path / "p"), "--cluster", "slurm", "--cores", "4",
                 "--dry-run"]) == 0
    script = capsys.readouterr().out
    assert "#SBATCH --cpus-per-task=4" in script and "--nworkers 4" in script
    assert not (tmp_path / "p").exists()
    assert main(["power", "--out", str(tmp_path / "p"), "--dry-run"]) == 2
