"""The PsychoPy session app: trial plans, sessions at the CRT, simulated observers.

Public API
----------
check_participant_id, make_plan, load_or_create_plan, plan_path, participant_seed, PLAN_COLUMNS
    Participant ids and trial plans.
SESSION_COLUMNS, DataFileError, SessionWriter, read_session, read_slider_histories,
read_run_events, session_path, sliders_path, runs_path, simulated_rows
    Session data files (one CSV row per trial, appended and fsynced; one torn-tail rule) and
    which rows a simulated observer answered.
Observer, make_observer, simulate_dataset, write_simulated_sessions, load_observer_params,
OBSERVER_KINDS, write_observer_params
    Simulated observers (``ideal``, ``humanlike``; parameters in ``observers.toml``).
fit_observer_params, ObserverFitError
    Fit the observers' parameters to a lab's sessions (``python -m experiment fit-observer``);
    imported on first use (scipy).

Study, StudyError, load_study, read_study_trials
    Another lab's rating study, described by its ``study.toml`` (trial files read as written).
load_rating_observers, fit_rating_observers, write_rating_observers, rating_levels,
rating_probs, rating_nll, rating_mean
    The one-response rating observer fitted to such a study (``fit-observer --study``);
    imported on first use (scipy).

run_session, SessionRequest, SessionOutcome, TrialResult, PreflightError
    The session app (``python -m experiment run``); imported on first use, so that
    ``import experiment`` stays light (no PsychoPy, no stimuli/calibration packages).

Importing this package opens no window and imports no PsychoPy.
"""

from experiment.datafile import (
    SESSION_COLUMNS,
    DataFileError,
    SessionWriter,
    read_run_events,
    read_session,
    read_slider_histories,
    runs_path,
    session_path,
    simulated_rows,
    sliders_path,
)
from experiment.observers import (
    OBSERVER_KINDS,
    Observer,
    load_observer_params,
    make_observer,
    simulate_dataset,
    write_observer_params,
    write_simulated_sessions,
)
from experiment.participants import check_participant_id
from experiment.plan import (
    PLAN_COLUMNS,
    PlanError,
    load_or_create_plan,
    make_plan,
    participant_seed,
    plan_path,
)
from experiment.study import Study, StudyError, load_study, read_study_trials

_LAZY = {"run_session": "experiment.session", "SessionRequest": "experiment.session",
         "SessionOutcome": "experiment.session", "TrialResult": "experiment.trial",
         "PreflightError": "experiment.checks",
         "fit_observer_params": "experiment.observer_fit",
         "ObserverFitError": "experiment.observer_fit",
         **{name: "experiment.rating_observer" for name in (
             "load_rating_observers", "fit_rating_observers", "write_rating_observers",
             "rating_levels", "rating_probs", "rating_nll", "rating_mean")}}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'experiment' has no attribute {name!r}")


__all__ = [
    "OBSERVER_KINDS",
    "PLAN_COLUMNS",
    "SESSION_COLUMNS",
    "DataFileError",
    "Observer",
    "ObserverFitError",
    "PlanError",
    "PreflightError",
    "SessionOutcome",
    "SessionRequest",
    "SessionWriter",
    "Study",
    "StudyError",
    "TrialResult",
    "check_participant_id",
    "fit_observer_params",
    "fit_rating_observers",
    "load_observer_params",
    "load_or_create_plan",
    "load_rating_observers",
    "load_study",
    "make_observer",
    "make_plan",
    "participant_seed",
    "plan_path",
    "rating_levels",
    "rating_mean",
    "rating_nll",
    "rating_probs",
    "read_run_events",
    "read_session",
    "read_slider_histories",
    "read_study_trials",
    "run_session",
    "runs_path",
    "session_path",
    "simulate_dataset",
    "simulated_rows",
    "sliders_path",
    "write_observer_params",
    "write_rating_observers",
    "write_simulated_sessions",
]
