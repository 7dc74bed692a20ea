"""Simulated observers of the matching task: the same objects drive the app, the analysis checks
and the sim-to-real diagnosis.

Two kinds, parameters in ``experiment/observers.toml`` (or a table passed as ``params``, or a
file fitted to a lab's own pilot by :func:`experiment.fit_observer_params`,
``python -m experiment fit-observer``):

``ideal``
    Truth plus trial noise: ``depth_hat = depth + e_d``, ``gloss_hat = gloss + e_g``.
``humanlike``
    The source study's pattern. Each observer draws its own intercepts and slopes once (random effects);
    depth is compressed towards the middle of the scale and depth leaks into gloss (deeper arrays
    look glossier), gloss does not leak into depth::

        depth_hat = m_d + b_d (depth - m_d) + a_d + e_d
        gloss_hat = m_g + b_g (gloss - m_g) + c (depth - m_d) + k (gloss - m_g)(depth - m_d)
                    + a_g + e_g

    with ``m_d`` (cm) and ``m_g`` (%) the slider's middle in physical units, ``b_d < 1`` the depth
    compression, ``c`` the crosstalk (% per cm) and ``k`` the interaction (per cm).

Answers are slider positions (the inverse of the design's slider mapping), clipped to the
slider's range as a real slider clips them.
"""

from __future__ import annotations

import copy
import json
import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd

from experiment.datafile import (
    SESSION_COLUMNS,
    SIMULATED_CALIBRATION_ID,
    SessionWriter,
    session_path,
    simulated_app_version,
)
from experiment.plan import make_plan, participant_seed
from labfiles import LabFileError, atomic_write_text, read_toml, write_new_file
from studydesign import SliderSpec, StudyDesign, load_design

__all__ = [
    "OBSERVER_KINDS",
    "Observer",
    "default_observers_path",
    "load_observer_params",
    "make_observer",
    "simulate_dataset",
    "write_observer_params",
    "write_simulated_sessions",
]

OBSERVER_KINDS = ("ideal", "humanlike")
#: The pause between a response and the next onset in simulated data (s); the app's is measured.
_SIMULATED_ITI_S = 0.5


def default_observers_path() -> Path:
    """The shipped parameter file, ``experiment/observers.toml``."""
    return Path(__file__).with_name("observers.toml")


def load_observer_params(path=None) -> dict:
    """Read an observers parameter file (default: the shipped one) -> ``{kind: table}``.

    A fitted file (``python -m experiment fit-observer``) also has a ``fit`` table (how, when and
    on which sessions it was fitted); it is returned as read.

    Raises
    ------
    ValueError
        The file is missing, is not TOML, lacks a kind's table or one of its parameters, or
        holds ``nan`` or ``inf`` in a kind's table (named as ``humanlike.gloss_noise_pct.mean``).
    """
    path = Path(path) if path is not None else default_observers_path()
    try:
        raw = read_toml(path)
    except FileNotFoundError as exc:
        raise ValueError(f"observer parameter file {path} does not exist") from exc
    except IsADirectoryError as exc:
        raise ValueError(f"observer parameter file {path} is a folder; give an observers "
                         ".toml file") from exc
    except LabFileError as exc:
        raise ValueError(f"observer parameter file {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"observer parameter file {path} is not valid TOML ({exc}); give an "
                         "observers.toml such as experiment/observers.toml or the output of "
                         "python -m experiment fit-observer") from exc
    missing = [k for k in OBSERVER_KINDS if k not in raw]
    if missing:
        raise ValueError(f"observer parameter file {path} lacks the tables {missing}")
    for kind in OBSERVER_KINDS:
        table = raw[kind]
        lacking = [k for k in _REQUIRED[kind] if not isinstance(table, Mapping) or k not in table]
        if lacking:
            raise ValueError(f"observer parameter file {path}: [{kind}] lacks {lacking}")
        _refuse_non_finite(table, path, kind)
    return raw


def _refuse_non_finite(value, path, key: str) -> None:
    """TOML reads ``nan`` and ``inf`` as numbers; no observer parameter may be either (a noise
    SD of nan passed every check written as ``x < 0`` and made every simulated answer nan).
    The ``[fit]`` table is not checked: a standard error may be nan there."""
    if isinstance(value, Mapping):
        for k, v in value.items():
            _refuse_non_finite(v, path, f"{key}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _refuse_non_finite(v, path, f"{key}[{i}]")
    elif isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"observer parameter file {path}: {key} = {value} is not a finite "
                         "number; write a number there (see experiment/observers.toml), or refit "
                         "the file with python -m experiment fit-observer")


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key, ensure_ascii=False)


def _toml_value(value, where: str) -> str:
    if isinstance(value, bool | np.bool_):
        return "true" if value else "false"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        v = float(value)
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v, where) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v, where)}"
                                for k, v in value.items()) + " }"
    raise TypeError(f"observer parameter {where} = {value!r} cannot be written to TOML")


def _is_inline(value) -> bool:
    """A ``{mean, sd}`` random effect is written inline, as in the shipped file."""
    return isinstance(value, Mapping) and bool(value) and set(value) <= {"mean", "sd"}


def _toml_table(name: str, table: Mapping) -> list[str]:
    lines = [f"[{name}]"]
    subtables = []
    for key, value in table.items():
        if isinstance(value, Mapping) and not _is_inline(value):
            subtables.append((f"{name}.{_toml_key(key)}", value))
        else:
            lines.append(f"{_toml_key(key)} = {_toml_value(value, f'{name}.{key}')}")
    for sub_name, sub in subtables:
        lines += ["", *_toml_table(sub_name, sub)]
    return lines


def observer_params_toml(params: Mapping) -> str:
    """The TOML text of an observers parameter table (what :func:`load_observer_params` reads)."""
    missing = [k for k in OBSERVER_KINDS if k not in params]
    if missing:
        raise ValueError(f"observer parameters lack the tables {missing}")
    lines = ["# Simulated observers of the gloss x depth matching task (experiment.observers).",
             "# Units in the names (cm, %, s); { mean, sd } is drawn once per observer."]
    if "fit" in params:
        lines.append("# Fitted to session data by python -m experiment fit-observer: see [fit].")
    for name, table in params.items():
        if not isinstance(table, Mapping):
            raise TypeError(f"observer parameters: {name} = {table!r} is not a table")
        lines += ["", *_toml_table(_toml_key(name), table)]
    return "\n".join(lines) + "\n"


def write_observer_params(path, params: Mapping, *, overwrite: bool = False) -> Path:
    """Write an observers parameter file atomically (fsynced, the umask's permissions).

    Parameters
    ----------
    path : path-like
        The ``.toml`` to write.
    params : mapping
        ``{"ideal": {...}, "humanlike": {...}, "fit": {...}}`` as
        :func:`experiment.fit_observer_params` returns (``fit`` optional); the file reads back
        equal with :func:`load_observer_params`.
    overwrite : bool
        Replace an existing file (atomically). By default an existing file is never replaced.

    Raises
    ------
    FileExistsError
        ``path`` exists and ``overwrite`` is false.
    ValueError
        A kind's table is missing or incomplete.
    """
    text = observer_params_toml(params)
    check = tomllib.loads(text)
    for kind in OBSERVER_KINDS:
        lacking = [k for k in _REQUIRED[kind] if k not in check[kind]]
        if lacking:
            raise ValueError(f"observer parameters: [{kind}] lacks {lacking}")
    path = Path(path)
    if overwrite:
        return atomic_write_text(path, text)
    return write_new_file(path, text)


def _draw(spec, name: str, rng: np.random.Generator) -> float:
    """A fixed number, or one draw from ``{mean, sd}`` (a per-observer random effect)."""
    if isinstance(spec, Mapping):
        if set(spec) != {"mean", "sd"} or spec["sd"] < 0:
            raise ValueError(f"observer parameter {name} = {dict(spec)}; give a number or "
                             "{ mean = ..., sd = ... } with sd >= 0")
        return float(rng.normal(spec["mean"], spec["sd"]))
    if not isinstance(spec, (int, float)):
        raise TypeError(f"observer parameter {name} = {spec!r} is not a number")
    return float(spec)


#: Parameters that are spreads: a fixed value must be >= 0, a drawn one is redrawn until it is.
_NON_NEGATIVE = ("depth_noise_cm", "gloss_noise_pct", "rt_log_sd")

_REQUIRED = {
    "ideal": ("depth_noise_cm", "gloss_noise_pct", "rt_median_s", "rt_log_sd"),
    "humanlike": ("depth_slope", "depth_intercept_cm", "depth_noise_cm", "gloss_slope",
                  "gloss_intercept_pct", "crosstalk_pct_per_cm", "interaction_per_cm",
                  "gloss_noise_pct", "rt_median_s", "rt_log_sd"),
}


@dataclass(frozen=True)
class Observer:
    """One simulated participant: its kind and its own drawn parameters.

    Attributes
    ----------
    kind : {"ideal", "humanlike"}
    participant : str
    params : dict of str to float
        This observer's parameters (after drawing its random effects), units in the names.
    slider : SliderSpec
        The design's slider, to convert physical estimates into slider positions.
    """

    kind: str
    participant: str
    params: dict
    slider: SliderSpec = field(repr=False)

    def _mid(self) -> tuple[float, float]:
        mid = 0.5 * (self.slider.min + self.slider.max)
        return float(self.slider.to_depth_cm(mid)), float(self.slider.to_gloss_pct(mid))

    def estimate(self, true_gloss_pct, true_depth_cm, rng: np.random.Generator):
        """Perceived gloss (%) and depth (cm), before the slider (arrays of one shape)."""
        gloss = np.asarray(true_gloss_pct, dtype=float)
        depth = np.asarray(true_depth_cm, dtype=float)
        p = self.params
        e_d = rng.normal(0.0, p["depth_noise_cm"], depth.shape)
        e_g = rng.normal(0.0, p["gloss_noise_pct"], gloss.shape)
        if self.kind == "ideal":
            return gloss + e_g, depth + e_d
        m_d, m_g = self._mid()
        depth_hat = m_d + p["depth_slope"] * (depth - m_d) + p["depth_intercept_cm"] + e_d
        gloss_hat = (m_g + p["gloss_slope"] * (gloss - m_g)
                     + p["crosstalk_pct_per_cm"] * (depth - m_d)
                     + p["interaction_per_cm"] * (gloss - m_g) * (depth - m_d)
                     + p["gloss_intercept_pct"] + e_g)
        return gloss_hat, depth_hat

    def to_slider(self, gloss_pct, depth_cm):
        """Physical estimates (%, cm) -> slider positions clipped to [slider.min, slider.max]
        (the design's own conversion, :meth:`studydesign.SliderSpec.from_gloss_pct`)."""
        return (self.slider.from_gloss_pct(gloss_pct, clip=True),
                self.slider.from_depth_cm(depth_cm, clip=True))

    def respond(self, trial_row, rng: np.random.Generator) -> tuple[float, float]:
        """Answer one trial.

        Parameters
        ----------
        trial_row : mapping
            A plan row; uses ``true_gloss_pct`` (%) and ``true_depth_cm`` (cm).
        rng : numpy.random.Generator

        Returns
        -------
        (gloss_match, depth_match) : tuple of float
            Slider positions in [slider.min, slider.max] (1-11 in the shipped design).
        """
        g, d = self.estimate(trial_row["true_gloss_pct"], trial_row["true_depth_cm"], rng)
        gv, dv = self.to_slider(g, d)
        return float(gv), float(dv)

    def respond_all(self, plan: pd.DataFrame, rng: np.random.Generator):
        """Vectorised :meth:`respond` over a plan -> (gloss_match, depth_match) arrays."""
        g, d = self.estimate(plan["true_gloss_pct"].to_numpy(), plan["true_depth_cm"].to_numpy(),
                             rng)
        return self.to_slider(g, d)

    def response_time_s(self, rng: np.random.Generator, size=None):
        """Log-normal response times (s) around this observer's median."""
        median = max(self.params["rt_median_s"], 0.2)
        return median * np.exp(rng.normal(0.0, self.params["rt_log_sd"], size))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "participant": self.participant, "params": dict(self.params)}


def make_observer(kind: str, participant: str, rng: np.random.Generator, params=None, *,
                  design: StudyDesign | None = None) -> Observer:
    """Make one simulated observer, drawing its own random effects from ``rng``.

    Parameters
    ----------
    kind : {"ideal", "humanlike"}
    participant : str
        Participant id (used to name its plan and files).
    rng : numpy.random.Generator
        Draws the observer-specific parameters.
    params : dict, optional
        The kind's parameter table (as in ``observers.toml``); default: the shipped file's.
        A number is fixed; ``{mean, sd}`` is drawn per observer (the noise SDs and
        ``rt_log_sd`` from the normal truncated at 0).
    design : StudyDesign, optional
        Supplies the slider mapping; default: the shipped design.

    Raises
    ------
    ValueError
        Unknown kind, bad participant id, or a parameter table missing names or with bad values.
    """
    from experiment.participants import check_participant_id

    check_participant_id(participant)
    if kind not in OBSERVER_KINDS:
        raise ValueError(f"unknown observer kind {kind!r}; use one of {OBSERVER_KINDS}")
    table = copy.deepcopy(params if params is not None else load_observer_params()[kind])
    missing = [k for k in _REQUIRED[kind] if k not in table]
    if missing:
        raise ValueError(f"{kind} observer parameters lack {missing}")
    drawn = {}
    for name in _REQUIRED[kind]:
        value = _draw(table[name], name, rng)
        if name in _NON_NEGATIVE and isinstance(table[name], Mapping):
            if table[name]["mean"] < 0:
                raise ValueError(f"{kind} observer parameter {name}: mean "
                                 f"{table[name]['mean']} must be >= 0")
            # A spread fitted to a pilot may reach below 0 now and then: draw again (the
            # normal truncated at 0), as a real observer's noise is never negative.
            while value < 0:
                value = _draw(table[name], name, rng)
        if name in _NON_NEGATIVE and value < 0:
            raise ValueError(f"{kind} observer parameter {name} = {value} must be >= 0")
        drawn[name] = value
    design = design if design is not None else load_design()
    return Observer(kind=kind, participant=participant, params=drawn, slider=design.slider)


def _plan(design: StudyDesign, participant: str) -> pd.DataFrame:
    """The plan the app would make for this participant (seeded by the participant id)."""
    seed = participant_seed(participant)
    return make_plan(design, participant, np.random.default_rng(seed), seed=seed)


def simulate_dataset(design: StudyDesign, observers, rng: np.random.Generator, *,
                     calibration_id: str = SIMULATED_CALIBRATION_ID) -> pd.DataFrame:
    """Every observer answers its whole plan (all sessions), without the app.

    Each observer's plan is the one ``python -m experiment run`` makes for that participant id
    (``make_plan`` seeded with ``participant_seed``), so simulated and app-run sessions show the
    same stimuli in the same order.

    Parameters
    ----------
    design : StudyDesign
    observers : sequence of Observer
        Participant ids must be distinct.
    rng : numpy.random.Generator
        Trial noise and response times.
    calibration_id : str

    Returns
    -------
    DataFrame
        ``SESSION_COLUMNS``; one row per participant and stimulus, sorted by participant,
        session and trial. ``onset_s`` is each session's cumulative time (rt + 0.5 s pause),
        ``dropped_frames`` 0, ``app_version`` marks the rows as simulated.
    """
    ids = [o.participant for o in observers]
    if len(set(ids)) != len(ids):
        raise ValueError(f"observer participant ids repeat: {ids}")
    start = datetime.now(UTC).replace(microsecond=0)
    frames = []
    for obs in observers:
        if obs.slider != design.slider:
            raise ValueError(f"observer {obs.participant} was made for another slider "
                             f"({obs.slider}); pass design= to make_observer")
        plan = _plan(design, obs.participant).drop(columns="seed")
        gloss, depth = obs.respond_all(plan, rng)
        plan["gloss_match"] = gloss
        plan["depth_match"] = depth
        plan["rt_s"] = obs.response_time_s(rng, len(plan))
        onset = np.zeros(len(plan))
        for idx in plan.groupby("session").indices.values():
            gaps = plan["rt_s"].to_numpy()[idx] + _SIMULATED_ITI_S
            onset[idx] = np.concatenate([[0.0], np.cumsum(gaps)[:-1]])
        plan["onset_s"] = onset
        plan["dropped_frames"] = 0
        plan["timestamp_utc"] = [
            (start + timedelta(seconds=float(t + r))).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
            for t, r in zip(onset, plan["rt_s"])
        ]
        plan["app_version"] = simulated_app_version(obs.kind, through_app=False)
        plan["calibration_id"] = calibration_id
        frames.append(plan[list(SESSION_COLUMNS)])
    out = pd.concat(frames, ignore_index=True)
    return out.sort_values(["participant", "session", "trial"], ignore_index=True)


def write_simulated_sessions(folder, design: StudyDesign, observers, rng: np.random.Generator,
                             **kwargs) -> list[Path]:
    """Simulate (see :func:`simulate_dataset`) and write ``folder/sessions/<p>_s<n>.csv``.

    Existing session files are never overwritten: ``FileExistsError`` names the first one.
    """
    frame = simulate_dataset(design, observers, rng, **kwargs)
    groups = list(frame.groupby(["participant", "session"]))
    exists = [p for p in (session_path(folder, w, int(s)) for (w, s), _ in groups) if p.exists()]
    if exists:  # checked first, so that nothing is written when anything would be overwritten
        raise FileExistsError(17, "session file exists", str(exists[0]))
    paths = []
    for (who, session), rows in groups:
        # The app's own writer: one format and one torn-tail rule for simulated and real rows.
        with SessionWriter(folder, who, int(session), sliders=False) as writer:
            writer.extend(rows.to_dict("records"))
        paths.append(writer.path)
    return paths
