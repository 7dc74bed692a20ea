"""Another lab's rating or matching study, read as it comes: ``study.toml`` beside its trial files.

A lab describes its study in a ``study.toml`` (protocol.md, "Another lab's study"); its keys
are the interface::

    name  = "Storrs, Anderson & Fleming 2021, experiment 1"
    files = "*_gloss_ratings_task_*.csv"      # the trial files, a glob in the study's folder

    [columns]                                 # column names as the lab's tool wrote them
    participant = "participant ID (two digits, e.g. 01)"
    stimulus    = "trials_1.thisIndex"
    trial       = "trials_1.thisN"            # presentation order within a participant
    response    = "rating"
    rt_s        = "decisionTime"              # optional

    [response]
    estimates = "true_gloss"                  # the stimulus factor the response judges
    scale     = [1, 6]                        # the response scale's ends
    step      = 1                             # its steps (0 or absent: continuous)
    labels    = [1, 6]                        # optional: labelled points, if coarser than steps

    [stimuli]
    table = "stimuli.csv"                     # one row per stimulus: its id and its factors
    id    = "stimulus"

Trial files are read as labs' tools write them (:func:`read_lab_csv`): a UTF-8 byte-order mark,
CRLF line ends, quoted fields, a trailing comma on every line, and a header in which a column
name holding a comma was left unquoted (PsychoPy's "participant ID (two digits, e.g. 01)"), so
the header has one field more than the rows: that header is repaired where the joined name is
one ``[columns]`` names, and the repair is said; otherwise it is refused with the fix.
"""

from __future__ import annotations

import csv
import difflib
import io
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from labfiles import LabFileError, read_text, read_toml

__all__ = ["Study", "StudyError", "load_study", "read_lab_csv", "read_study_trials"]

#: The [columns] keys: the required ones, then the optional ones.
_REQUIRED_COLUMNS = ("participant", "stimulus", "trial", "response")
_OPTIONAL_COLUMNS = ("rt_s",)
#: Every key a study.toml may hold, per table ("" the top level); any other is a typo.
_KEYS = {"": ("name", "files", "columns", "response", "stimuli"),
         "columns": _REQUIRED_COLUMNS + _OPTIONAL_COLUMNS,
         "response": ("estimates", "scale", "step", "labels"),
         "stimuli": ("table", "id")}
#: Fewest trials a participant may have: the rating observer has four parameters, and a
#: participant is a split half of the diagnosis's consistency figure.
MIN_TRIALS = 10


class StudyError(ValueError):
    """A study description or trial file that cannot be read; the message names the fix."""


@dataclass(frozen=True)
class Study:
    """A study as its ``study.toml`` describes it (see the module docstring).

    Attributes
    ----------
    folder : Path
        The folder of the ``study.toml``; ``files`` and the stimuli table are relative to it.
    name : str
    files : str
        Glob of the trial files.
    columns : dict
        ``{participant, stimulus, trial, response[, rt_s]} -> column name in the files``.
    estimates : str
        The stimuli table's column the response is a judgement of (the factor).
    scale : tuple of float
        The response scale's ends (its units).
    step : float
        The scale's step (0: continuous).
    labels : tuple of float
        Labelled points of the scale where they are coarser than its steps, else ().
    stimuli_table : str
        The stimuli table's file (relative to ``folder``).
    stimulus_id : str
        Its id column.
    """

    folder: Path
    name: str
    files: str
    columns: dict
    estimates: str
    scale: tuple
    step: float
    labels: tuple
    stimuli_table: str
    stimulus_id: str

    @property
    def source(self) -> Path:
        return self.folder / "study.toml"


def _need(table: dict, key: str, where: str, path: Path):
    if key not in table:
        raise StudyError(f"{path}: {where} lacks '{key}'; add it (protocol.md, 'Another lab's "
                         "study', lists the keys)")
    return table[key]


def _unknown_keys(raw: dict, path: Path) -> None:
    """Refuse keys a study.toml does not know (a typo such as ``stpe`` would otherwise be
    dropped without a word and its default used)."""
    bad = []
    for table, known in _KEYS.items():
        values = raw if not table else raw.get(table)
        if not isinstance(values, dict):
            continue
        for key in values:
            if key not in known:
                near = difflib.get_close_matches(key, known, n=1, cutoff=0.5)
                where = f"[{table}] {key}" if table else key
                bad.append(f"{where!r}" + (f" (did you mean {near[0]!r}?)" if near else ""))
    if bad:
        raise StudyError(f"{path}: unknown keys {', '.join(bad)}; rename or remove them (the "
                         "keys are listed in protocol.md, 'Another lab's study')")


def _check_labels(labels: tuple, scale: list, path: Path) -> None:
    outside = [v for v in labels if not scale[0] <= v <= scale[1]]
    if outside:
        raise StudyError(f"{path}: [response] labels {[f'{v:g}' for v in outside]} lie outside "
                         f"the scale {scale}; labels are points of the scale: fix labels or "
                         "scale")


def load_study(path) -> Study:
    """Read and check a ``study.toml``.

    Raises
    ------
    StudyError
        A missing file, invalid TOML, or a missing or malformed key (the message names it).
    """
    path = Path(path)
    if path.is_dir():
        path = path / "study.toml"
    try:
        raw = read_toml(path)  # a BOM, CRLF or UTF-16 (Notepad) as the project's own files
    except FileNotFoundError as exc:
        raise StudyError(f"{path} does not exist; describe the study in a study.toml beside "
                         "its trial files (protocol.md, 'Another lab's study')") from exc
    except LabFileError as exc:
        raise StudyError(str(exc)) from None
    except tomllib.TOMLDecodeError as exc:
        raise StudyError(f"{path} is not valid TOML ({exc}); fix the line it names") from exc
    _unknown_keys(raw, path)
    cols = _need(raw, "columns", "the file", path)
    columns = {k: str(_need(cols, k, "[columns]", path)) for k in _REQUIRED_COLUMNS}
    columns |= {k: str(cols[k]) for k in _OPTIONAL_COLUMNS if k in cols}
    if isinstance(cols.get("response"), list):
        raise StudyError(f"{path}: [columns] response is a list; a study.toml describes one "
                         "response (the glossdepth sessions' two are read without --study)")
    resp = _need(raw, "response", "the file", path)
    scale = _need(resp, "scale", "[response]", path)
    if (not isinstance(scale, list) or len(scale) != 2
            or not all(isinstance(v, (int, float)) for v in scale) or scale[0] >= scale[1]):
        raise StudyError(f"{path}: [response] scale = {scale!r}; write the ends as "
                         "[lowest, highest], e.g. scale = [1, 6]")
    step = float(resp.get("step", 0) or 0)
    span = float(scale[1] - scale[0])
    if step < 0 or (step > 0 and not math.isclose(span / step, round(span / step))):
        raise StudyError(f"{path}: [response] step = {step} does not divide the scale "
                         f"{scale}; give the scale's step (1 for integer ratings) or 0")
    labels = tuple(float(v) for v in resp.get("labels", ()))
    _check_labels(labels, scale, path)
    stim = _need(raw, "stimuli", "the file", path)
    return Study(folder=path.parent, name=str(raw.get("name", path.parent.name)),
                 files=str(_need(raw, "files", "the file", path)), columns=columns,
                 estimates=str(_need(resp, "estimates", "[response]", path)),
                 scale=(float(scale[0]), float(scale[1])), step=step, labels=labels,
                 stimuli_table=str(_need(stim, "table", "[stimuli]", path)),
                 stimulus_id=str(_need(stim, "id", "[stimuli]", path)))


def _join_split_name(header: list[str], names, path: Path) -> tuple[list[str], str]:
    """The header with the two fields that an unquoted comma split joined again, where the
    joined text is one of ``names``; raises with the fix otherwise."""
    for i in range(len(header) - 1):
        joined = f"{header[i]},{header[i + 1]}".strip()
        if joined in names:
            note = (f"{path.name}: the header's column name {joined!r} holds a comma but was "
                    "written unquoted, splitting it into two fields (the header has one field "
                    "more than the rows); joined again")
            return [h.strip() for h in header[:i]] + [joined] + [
                h.strip() for h in header[i + 2:]], note
    raise StudyError(
        f"{path}: the header has {len(header)} fields but every row {len(header) - 1}: a "
        "column name holding a comma was probably written unquoted. Quote it in the header "
        "line (\"name, with comma\"), or name it in study.toml's [columns] as it reads with "
        "the comma, so that it can be joined again")


def read_lab_csv(path, names=()) -> tuple[pd.DataFrame, list[str]]:
    """Read a CSV file as a lab's tool wrote it: every field as text.

    Parameters
    ----------
    path : path-like
    names : iterable of str
        Column names the caller needs; an unquoted name with a comma is joined again only
        where the joined text is one of them.

    Returns
    -------
    (DataFrame, notes)
        The rows (strings, blank lines dropped) and what was repaired, in words.

    Raises
    ------
    StudyError
        Rows of differing lengths, a header that cannot be repaired, duplicate names.
    """
    path = Path(path)
    try:  # a BOM, CRLF or UTF-16 decoded as labfiles does for every reader
        text = read_text(path)
    except LabFileError as exc:
        raise StudyError(str(exc)) from None
    rows = [r for r in csv.reader(io.StringIO(text, newline="")) if any(v.strip() for v in r)]
    if not rows:
        raise StudyError(f"{path} is empty; remove it or move it out of the study's folder")
    notes = []
    header, body = list(rows[0]), rows[1:]
    if header[-1].strip() == "" and all(r and r[-1].strip() == "" for r in body):
        header = header[:-1]
        body = [r[:-1] for r in body]
        notes.append(f"{path.name}: a trailing comma on every line (an empty last column; "
                     "dropped)")
    widths = {len(r) for r in body}
    if body and widths == {len(header) - 1}:
        header, note = _join_split_name(header, set(names), path)
        notes.append(note)
    header = [h.strip() for h in header]
    bad = [i + 2 for i, r in enumerate(body) if len(r) != len(header)]
    if bad:
        raise StudyError(f"{path}: lines {bad[:5]} have a number of fields other than the "
                         f"header's {len(header)}; quote fields that hold commas, or remove "
                         "the broken lines")
    dup = sorted({h for h in header if header.count(h) > 1 and h})
    if dup:
        raise StudyError(f"{path}: the header names {dup} more than once; rename them")
    return pd.DataFrame(body, columns=header, dtype=str), notes


def _numbers(frame: pd.DataFrame, column: str) -> pd.Series:
    values = pd.to_numeric(frame[column].str.strip(), errors="coerce")
    return values


def _stimuli(study: Study) -> pd.DataFrame:
    path = study.folder / study.stimuli_table
    if not path.exists():
        raise StudyError(f"{path} does not exist; write the stimuli table named by study.toml's "
                         "[stimuli] table (one row per stimulus: its id and its factors)")
    table, _ = read_lab_csv(path, (study.stimulus_id, study.estimates))
    for col in (study.stimulus_id, study.estimates):
        if col not in table.columns:
            raise StudyError(f"{path} has no column {col!r} (it has {list(table.columns)}); "
                             "fix [stimuli] id or [response] estimates in study.toml")
    factor = _numbers(table, study.estimates)
    if factor.isna().any():
        raise StudyError(f"{path}: {int(factor.isna().sum())} stimuli have no number in "
                         f"{study.estimates!r}; fill them in")
    ids = table[study.stimulus_id].str.strip()
    if ids.duplicated().any():
        raise StudyError(f"{path}: stimulus ids {sorted(set(ids[ids.duplicated()]))[:5]} occur "
                         "more than once; one row per stimulus")
    return pd.DataFrame({"stimulus": ids, "factor": factor.to_numpy(float)})


def read_study_trials(study: Study, participants=None) -> tuple[pd.DataFrame, list[str]]:
    """The study's trials, one row each: ``participant``, ``stimulus``, ``trial`` (order within
    the participant), ``response`` (the scale's units), ``rt_s`` (NaN without), ``factor``
    (the estimated factor, from the stimuli table), ``file``; sorted by participant and trial.

    Parameters
    ----------
    study : Study
    participants : iterable of str, optional
        Keep only these participants (as the files write their ids).

    Returns
    -------
    (DataFrame, notes)
        Notes: the repairs made, rows skipped (no response), responses off the scale's steps.

    Raises
    ------
    StudyError
        No files, a column missing, responses outside the scale, a stimulus not in the table.
    """
    frame, notes, n_files = _read_trial_files(study)
    frame, said = _numeric_responses(frame, study, n_files)
    notes += said
    if participants is not None:
        want = {str(p) for p in participants}
        absent = sorted(want - set(frame["participant"]))
        if absent:
            raise StudyError(f"participants {absent} are not in the study's files (it has "
                             f"{sorted(set(frame['participant']))}); fix --participants")
        frame = frame[frame["participant"].isin(want)]
    _check_trial_numbers(frame, study)
    frame, said = _on_the_scale(frame, study)
    notes += said
    stim = _stimuli(study)
    frame = frame.merge(stim, on="stimulus", how="left")
    unknown = sorted(set(frame.loc[frame["factor"].isna(), "stimulus"]))
    if unknown:
        raise StudyError(f"stimuli {unknown[:5]} of the trial files are not in "
                         f"{study.stimuli_table}; add them to the stimuli table")
    if frame["trial"].isna().any():
        raise StudyError(f"{int(frame['trial'].isna().sum())} rows have no number in the trial "
                         f"column {study.columns['trial']!r}; fix [columns] trial")
    frame = frame.sort_values(["participant", "trial"], ignore_index=True)
    return frame, _dedupe(notes)


def _read_trial_files(study: Study) -> tuple[pd.DataFrame, list[str], int]:
    """Every trial file's study columns, as written (stripped text), with its ``file`` name.

    Returns
    -------
    (DataFrame, notes, number of files)
        Notes: the repairs :func:`read_lab_csv` made.
    """
    files = sorted(study.folder.glob(study.files))
    if not files:
        raise StudyError(f"no trial files match {study.files!r} in {study.folder}; fix study.toml's "
                         "files (a glob relative to its folder)")
    names = list(study.columns.values())
    frames, notes = [], []
    for path in files:
        raw, said = read_lab_csv(path, names)
        notes += said
        missing = [n for n in names if n not in raw.columns]
        if missing:
            raise StudyError(f"{path} has no columns {missing} (it has {list(raw.columns)}); "
                             "fix [columns] in study.toml")
        out = pd.DataFrame({k: raw[c].str.strip() for k, c in study.columns.items()})
        out["file"] = path.name
        frames.append(out)
    return pd.concat(frames, ignore_index=True), notes, len(files)


def _numeric_responses(frame: pd.DataFrame, study: Study, n_files: int
                       ) -> tuple[pd.DataFrame, list[str]]:
    """Responses, trial numbers and response times as numbers (``rt_s`` NaN without); rows
    without a numeric response skipped, and a response column with none refused."""
    written = frame["response"].copy()
    for k in ("response", "trial", "rt_s"):
        if k in frame:
            frame[k] = pd.to_numeric(frame[k], errors="coerce")
    if "rt_s" not in frame:
        frame["rt_s"] = np.nan
    empty = frame["response"].isna()
    if empty.all():
        seen = sorted(set(written))[:3]
        raise StudyError(f"the response column {study.columns['response']!r} holds no number in "
                         f"any of the {len(frame)} rows of {n_files} file(s) (it holds "
                         f"{seen}); point study.toml's [columns] response at the column of "
                         "the responses")
    if empty.any():
        return frame[~empty], [f"{int(empty.sum())} rows without a numeric response (skipped)"]
    return frame, []


def _on_the_scale(frame: pd.DataFrame, study: Study) -> tuple[pd.DataFrame, list[str]]:
    """Refuse responses outside the scale; note an end of the scale no one used, and round
    responses off the scale's steps to the nearest step (saying so)."""
    lo, hi = study.scale
    out_of = (frame["response"] < lo) | (frame["response"] > hi)
    if out_of.any():
        raise StudyError(f"{int(out_of.sum())} responses lie outside the scale {[lo, hi]} (e.g. "
                         f"{frame.loc[out_of, 'response'].iloc[0]:g}); fix [response] scale")
    notes = _unused_scale_end(frame["response"], study)
    if study.step > 0:
        k = (frame["response"] - lo) / study.step
        off = ~np.isclose(k, np.round(k), atol=1e-6)
        if off.any():
            notes.append(f"{int(off.sum())} responses are not on the scale's steps of "
                         f"{study.step:g}; rounded to the nearest step")
            frame["response"] = lo + np.round(k) * study.step
    return frame, notes


def _check_trial_numbers(frame: pd.DataFrame, study: Study) -> None:
    """Refuse a participant whose trial numbers repeat (the trial column numbers the
    presentation order within a participant): a copy of a file, two files under one ID, or a
    trial column that restarts within a file; and a participant too small to fit or split."""
    col = study.columns["trial"]
    for pid, rows in frame.groupby("participant", sort=True):
        if not rows["trial"].duplicated().any():
            continue
        for name, own in rows.groupby("file", sort=True):
            counts = own["trial"].value_counts()
            if counts.max() > 1:
                raise StudyError(
                    f"{name}: the trial column {col!r} repeats its numbers within the file "
                    f"(trial {counts.idxmax():g} {int(counts.max())} times); it must number "
                    "the presentation order within a participant: point [columns] trial at "
                    "the column counting every trial (PsychoPy's trials.thisN, not "
                    "thisTrialN or thisRepN)")
        content = {name: own.drop(columns="file").sort_values("trial").to_numpy(str).tobytes()
                   for name, own in rows.groupby("file", sort=True)}
        names = sorted(content)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                if content[a] == content[b]:
                    raise StudyError(
                        f"{b} holds the same trials as {a} (participant {pid}): a copy of the "
                        "file; move the copy out of the study's folder")
        raise StudyError(
            f"participant {pid} has trials in {len(names)} files ({', '.join(names)}) with the "
            "same trial numbers: two people under one ID, or one person's sessions each "
            "numbered from the start; give each person their own ID (the participant column), "
            "or number a later session's trials on from the earlier one's")
    counts = frame.groupby("participant").size()
    few = counts[counts < MIN_TRIALS]
    if len(few):
        raise StudyError(
            f"participants {({k: int(v) for k, v in few.items()})} have fewer than {MIN_TRIALS} trials: too "
            "few to fit a rating observer (four parameters) or to be a split half of the "
            "diagnosis; leave them out with --participants, or move their files out of the "
            "study's folder")


def _unused_scale_end(response: pd.Series, study: Study) -> list[str]:
    """A note where no response comes within a third of the scale's span of one of its ends:
    a study.toml's scale copied from another study (the observer's model takes the ends as
    given: a wrong end moves its censoring). A note, not a refusal: a study whose stimuli
    never earn the top of the scale is possible."""
    lo, hi = study.scale
    if len(response) < 50:
        return []
    a, b = float(response.min()), float(response.max())
    span = hi - lo
    unused = [f"{end} ({lo if end == 'bottom' else hi:g})" for end, gap in
              (("bottom", a - lo), ("top", hi - b)) if gap > span / 3]
    if not unused:
        return []
    return [(f"no response of {len(response)} comes near the scale's {' or '.join(unused)}; "
             f"they lie in [{a:g}, {b:g}] of the scale [{lo:g}, {hi:g}]. If the scale is "
             "narrower, fix [response] scale in study.toml (the fit takes its ends as given)")]


def _dedupe(notes: list[str]) -> list[str]:
    """One note per kind of repair, counting the files it was made in."""
    kinds: dict[str, list[str]] = {}
    for n in notes:
        name, _, text = n.partition(": ")
        kinds.setdefault(text if text else n, []).append(name)
    out = []
    for text, where in kinds.items():
        out.append(text if len(where) == 1 and where[0] == text
                   else f"{len(where)} file(s) ({where[0]}, ...): {text}")
    return out
