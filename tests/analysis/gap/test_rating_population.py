"""A rating population needs several participants (issue 44 item 6): a fit to one is refused,
with the fix, by the command line and the function; a file of one participant's fit (written
before the refusal) is read, and the diagnosis says it cannot tell individual differences
apart instead of crediting them."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap.diagnose import diagnose
from experiment.__main__ import main as experiment_main
from experiment.rating_observer import fit_rating_observers, write_rating_observers
from experiment.study import load_study, read_study_trials
from studydesign import load_design
from tests.analysis.gap.rating_study import write_study


def test_a_rating_population_of_one_participant_is_refused_with_the_fix(tmp_path, capsys):
    st = write_study(tmp_path / "s", np.random.default_rng(3), n_participants=3)
    study = load_study(st)
    one, _ = read_study_trials(study, ["01"])
    with pytest.raises(ValueError, match=r"only 1 participant \(01\).*at least 2 "
                       r"participants.*--participants 01 02 03"):
        fit_rating_observers(one, study)
    out = tmp_path / "obs.toml"
    assert experiment_main(["fit-observer", str(tmp_path / "s"), "--study", str(st),
                            "--participants", "01", "--out", str(out)]) == 2
    assert "between-observer SDs need at least 2 participants" in capsys.readouterr().err
    assert not out.exists()


def test_a_one_participant_fit_is_not_credited_with_individual_differences(tmp_path):
    """Participants whose gains differ (SD 1.5 per unit of gloss) diagnosed against a file
    whose population is one participant's (SD 0.000): before, 'individual_differences'."""
    st = write_study(tmp_path / "s", np.random.default_rng(4), n_participants=4)
    study = load_study(st)
    two, _ = read_study_trials(study, ["01", "02"])
    params = fit_rating_observers(two, study)
    # As a fit of participant 01 alone was written before it was refused.
    params["rating"]["gain"]["sd"] = params["rating"]["offset"]["sd"] = 0.0
    params["fit"]["participants"] = ["01"]
    write_rating_observers(tmp_path / "obs.toml", params)
    d, _ = diagnose("observer", tmp_path / "s", tmp_path / "obs.toml", load_design(), seed=4,
                    n_boot=200, study=st, participants=["03", "04"])
    assert "individual_differences" not in [s["added"] for s in d.steps]
    assert any("individual differences cannot be told apart" in w for w in d.warnings)
    assert "individual_differences" in d.not_identifiable
