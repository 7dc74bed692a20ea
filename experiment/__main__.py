"""``python -m experiment``: the session app's command line.

``run``   run (or resume) a session at the CRT, or with a simulated observer under Xvfb;
``plan``  make or show a participant's trial plan;
``status``  how far a participant's sessions are (and whether a file has a torn tail);
``simulate``  write simulated session files without the app (observer model only);
``fit-observer``  fit the simulated observers' parameters to a lab's sessions (a pilot).

The data folder is ``--data``, else the lab's data root in the environment variable
``GLOSSDEPTH_DATA``; never the working directory, so the same command continues a session from
any directory. Messages print absolute paths.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from pathlib import Path

from experiment.run_command import main_run
from studydesign import DesignError, load_design

#: Environment variable naming the lab's data root (read here, at the command line only).
DATA_ENV = "GLOSSDEPTH_DATA"


class UsageError(ValueError):
    """The command line lacks something (exit status 2)."""


def data_folder(value: str | None) -> Path:
    """The data folder, absolute: ``--data``, else ``$GLOSSDEPTH_DATA``; never a default.

    Raises
    ------
    UsageError
        Neither is given, or either is a relative path: it would follow the working directory,
        and the same command typed in another directory would start the session over in
        another folder.
    """
    if value is not None and not value.strip():
        raise UsageError("--data is empty; type the data folder's absolute path, e.g. --data "
                         "/srv/glossdepth/data")
    if value:
        given = Path(value).expanduser()
        if not given.is_absolute():
            raise UsageError(
                f"--data {value} is a relative path, so the data folder would change with the "
                f"working directory (here {given.absolute()}; from another directory the "
                f"session would start over elsewhere); type the absolute path: --data "
                f"{given.absolute()}")
        return given
    value = os.environ.get(DATA_ENV)
    if not value:
        raise UsageError(
            f"no data folder: pass --data /path/to/the/lab/data, or set {DATA_ENV} to the lab's "
            "data root (the working directory is never used, so that the same command continues "
            "a session from any directory)")
    root = Path(value).expanduser()
    if not root.is_absolute():
        raise UsageError(
            f"{DATA_ENV}={value} is a relative path, so the data folder would change with the "
            f"working directory (here {root.absolute()}); set {DATA_ENV} to an absolute path, "
            "e.g. /srv/glossdepth/data, or pass --data")
    return root


def _cmd_plan(args) -> int:
    from experiment.plan import PlanError, load_or_create_plan, plan_path

    design = load_design(args.design)
    data = data_folder(args.data)
    try:
        plan = load_or_create_plan(design, args.participant, data)
    except (PlanError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"error: cannot write the plan in {data} ({exc.strerror}); give a writable "
              "folder with --data", file=sys.stderr)
        return 1
    counts = plan.groupby("session").size().to_dict()
    print(f"plan: {plan_path(data, args.participant)} (seed {plan['seed'].iloc[0]}, "
          f"trials per session {counts})")
    return 0


#: Debian packages Qt's X11 plugin (PsychoPy's dialog) needs beyond PsychoPy's own: library -> package.
_QT_XCB_LIBS = {"xcb-icccm": "libxcb-icccm4", "xcb-keysyms": "libxcb-keysyms1",
                "xcb-cursor": "libxcb-cursor0"}


def _dialog_problem() -> str | None:
    """Why PsychoPy's (Qt) dialog cannot open here, or None. Qt aborts the process when its X11
    plugin cannot load, so this is checked first."""
    import ctypes.util
    import os

    if not os.environ.get("DISPLAY"):
        return "there is no X display (DISPLAY is not set)"
    missing = [pkg for lib, pkg in _QT_XCB_LIBS.items() if ctypes.util.find_library(lib) is None]
    if missing:
        return f"Qt's X11 plugin needs the Debian packages {missing} (apt-get install them)"
    return None


_FIELDS = ("participant", "session", "stimuli", "calibration")
_TIPS = {"participant": "e.g. P01 (letters, digits, - or _)", "session": "1 or 2",
         "stimuli": "path of the stimuli's manifest.csv",
         "calibration": "path of the calibration's calibration.json"}


def _ask(values: dict) -> dict | None:
    """PsychoPy's dialog for the fields the command line left out; None when cancelled."""
    from psychopy import gui

    info = {k: values[k] or "" for k in _FIELDS}
    dlg = gui.DlgFromDict(info, title="glossdepth session", order=list(_FIELDS),
                          fixed=[k for k in _FIELDS if values[k]], tip=_TIPS)
    if not dlg.OK:
        return None
    return {k: str(v).strip() or None for k, v in info.items()}


def _cmd_run(args) -> int:
    from experiment.session import SessionRequest

    design = load_design(args.design)
    data = data_folder(args.data)
    values = {"participant": args.participant, "session": args.session,
              "stimuli": args.stimuli, "calibration": args.calibration}
    if args.fast and not args.simulate:
        print("error: --fast is for simulated runs (it does not wait for the vertical blank, so "
              "onsets and frame counts would be wrong with a participant)", file=sys.stderr)
        return 2
    problem = _observer_params_problem(args.observer_params, args.simulate)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    if any(v is None for v in values.values()):
        if args.simulate:
            print("error: --participant, --session, --stimuli and --calibration are required "
                  "with --simulate", file=sys.stderr)
            return 2
        problem = _dialog_problem()
        if problem is not None:
            print(f"error: cannot show the session dialog: {problem}; or give --participant, "
                  "--session, --stimuli and --calibration on the command line", file=sys.stderr)
            return 2
        values = _ask(values)
        if values is None:
            print("cancelled: no session run", file=sys.stderr)
            return 1
    req = SessionRequest(
        design=design, participant=values["participant"], session=values["session"],
        manifest=values["stimuli"], calibration=values["calibration"], data_dir=str(data),
        max_calibration_age_days=args.max_calibration_age_days, simulate=args.simulate,
        observer_params=args.observer_params, seed=args.seed, fast=args.fast,
        fullscr=args.fullscr, accept_calibration_mismatch=args.accept_calibration_mismatch,
        accept_unverified_resume=args.accept_unverified_resume,
        screenshot=args.screenshot, quit_at_trial=args.simulate_quit_at,
        early_space_probability=args.simulate_early_space,
    )
    return main_run(req)


def _cmd_status(args) -> int:
    from experiment.status import print_status

    return print_status(load_design(args.design), data_folder(args.data), args.participant)


def _cmd_simulate(args) -> int:
    import numpy as np

    from experiment.observers import (
        load_observer_params,
        make_observer,
        write_simulated_sessions,
    )

    design = load_design(args.design)
    rng = np.random.default_rng(args.seed)
    _check_participants(args.participants)
    if not args.data.strip():
        raise UsageError("--data is empty: give it a folder (an empty name would write into the "
                         "current folder)")
    problem = _observer_params_problem(args.observer_params, args.observer)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        params = load_observer_params(args.observer_params)[args.observer]
        observers = [make_observer(args.observer, p, rng, params, design=design)
                     for p in args.participants]
    except (ValueError, TypeError, KeyError) as exc:
        print(f"error: --observer-params {args.observer_params}: {exc}", file=sys.stderr)
        return 2
    try:
        paths = write_simulated_sessions(Path(args.data).absolute(), design, observers, rng)
    except FileExistsError as exc:
        print(f"error: {exc.filename} exists; session files are never overwritten",
              file=sys.stderr)
        return 1
    print(f"{len(paths)} session files ({args.observer} observers, seed {args.seed}) in "
          f"{paths[0].parent}")
    return 0


def _check_participants(ids: list[str]) -> None:
    """Refuse invalid or repeated ``--participants`` (ids differing only in case name one
    person, and one file on a case-insensitive disk), in the option's name."""
    from experiment.participants import check_participant_id

    seen: dict[str, str] = {}
    for pid in ids:
        try:
            check_participant_id(pid)
        except ValueError as exc:
            raise UsageError(f"--participants: {exc}") from None
        if pid.casefold() in seen:
            raise UsageError(f"--participants names {seen[pid.casefold()]!r} and {pid!r}: give "
                             "each participant once (ids that differ only in case are one "
                             "person)")
        seen[pid.casefold()] = pid


def _seed(text: str) -> int:
    """A seed for numpy's generator: a whole number >= 0 (argparse type)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value}: a seed is a whole number >= 0 (e.g. 1)")
    return value


# ---- fit-observer: the simulated observers fitted to a lab's own sessions -------------------
def _observer_params_problem(path, kind) -> str | None:
    """Why an --observer-params file cannot drive a simulated observer of ``kind``, or None."""
    if path is None:
        return None
    if kind is None:
        return "--observer-params is for simulated observers: add --simulate humanlike (or ideal)"
    import numpy as np

    from experiment.observers import load_observer_params, make_observer

    try:
        params = load_observer_params(path)
        make_observer(kind, "CHECK", np.random.default_rng(0), params[kind])
    except (ValueError, TypeError) as exc:
        return str(exc)
    return None


def _cmd_fit_study(args) -> int:
    """fit-observer --study: the rating observer of another lab's study (one response)."""
    from pathlib import Path

    from experiment.rating_observer import fit_rating_observers, write_rating_observers
    from experiment.study import StudyError, load_study, read_study_trials

    out = Path(args.out)
    if out.exists():
        print(f"error: {out} exists and is never overwritten; choose another --out or move it "
              "aside", file=sys.stderr)
        return 1
    try:
        study = load_study(args.study)
        if len(args.sessions) != 1 or Path(args.sessions[0]).resolve() != study.folder.resolve():
            raise StudyError(f"with --study the trial files are those study.toml names in its "
                             f"own folder ({study.folder}); pass that folder as DIR")
        frame, notes = read_study_trials(study, args.participants)
        params = fit_rating_observers(frame, study)
        if notes:  # kept in the file beside the fit they qualify
            params["fit"]["notes"] = list(notes)
    except (StudyError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_rating_observers(out, params)
    pop, per = params["rating"], params["participants"]
    print(f"fitted {len(per)} participants, {params['fit']['n_trials']} trials of "
          f"{study.name!r} ({study.columns['response']!r} judging {study.estimates!r} on "
          f"{study.scale[0]:g}-{study.scale[1]:g}, step {study.step:g})")
    print(f"{'participant':12s} {'gain':>8s} {'offset':>8s} {'noise':>8s} {'lapses':>8s}")
    for pid, p in per.items():
        print(f"{pid:12s} {p['gain']:8.3f} {p['offset']:8.3f} {p['noise']:8.3f} "
              f"{p['lapse_rate']:8.3f}")
    print(f"population: gain {pop['gain']['mean']:.3f} (sd {pop['gain']['sd']:.3f}), offset "
          f"{pop['offset']['mean']:.3f} (sd {pop['offset']['sd']:.3f}), noise "
          f"{pop['noise']:.3f}, lapse rate {pop['lapse_rate']:.3f}")
    print(f"wrote {out}: diagnose other participants with python -m analysis gap diagnose "
          f"--layer observer --real {study.folder} --study {study.source} --sim {out} "
          "--participants ...")
    return 0


def _cmd_fit_observer(args) -> int:
    import warnings
    from pathlib import Path

    from experiment.observer_fit import (
        HUMANLIKE_PARAMS,
        ObserverFitError,
        fit_observer_params,
        read_sessions_for_fit,
    )
    from experiment.observers import write_observer_params
    from labfiles.outdir import OutDirError, prepare_out_dir, write_error_line

    if args.study:
        return _cmd_fit_study(args)
    if args.participants:
        print("error: --participants is for --study (a session folder is fitted whole)",
              file=sys.stderr)
        return 2
    design = load_design(args.design)
    out = Path(args.out)
    if not args.out.strip() or out.is_dir():
        print(f"error: --out {args.out!r} is {'a folder' if args.out.strip() else 'empty'}: give "
              "it a file name, e.g. --out observers.toml", file=sys.stderr)
        return 2
    if out.exists():
        print(f"error: {out} exists and is never overwritten; choose another --out or move it "
              "aside", file=sys.stderr)
        return 1
    try:
        prepare_out_dir(out.parent)  # before the fit: a read-only folder costs seconds
    except OutDirError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    try:
        frame, simulated, files = read_sessions_for_fit(args.sessions)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            params = fit_observer_params(frame, design, kind=args.kind,
                                         simulated_sessions=simulated)
    except ObserverFitError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_observer_params(out, params)
    except FileExistsError:
        print(f"error: {out} appeared while fitting; it is never overwritten", file=sys.stderr)
        return 1
    except OSError as exc:  # the disk filled or went read-only during the fit
        print(f"error: {write_error_line(exc)}", file=sys.stderr)
        return 1
    fit, se = params["fit"], params["fit"]["standard_errors"]["humanlike"]
    if len(fit["simulated_sessions"]) == len(fit["sessions"]):
        print("note: every session comes from a simulated observer: this is a check of the fit, "
              "not the lab's observer", file=sys.stderr)
    print(f"fitted {fit['n_participants']} participants, {fit['n_trials']} trials from "
          f"{len(files)} files ({fit['n_censored']['gloss']} gloss and "
          f"{fit['n_censored']['depth']} depth answers at a slider end, fitted as censored)")
    print(f"{'humanlike parameter':24s} {'mean':>10s} {'(SE)':>9s} {'sd':>10s} {'(SE)':>9s}")
    for name in HUMANLIKE_PARAMS:
        v = params["humanlike"][name]
        print(f"{name:24s} {v['mean']:10.4g} ({se[name]['mean']:7.2g}) {v['sd']:10.4g} "
              f"({se[name]['sd']:7.2g})")
    print(f"ideal: {', '.join(f'{k} {v:.4g}' for k, v in params['ideal'].items())}")
    print(f"wrote {out}: use it with python -m experiment simulate --observer-params {out} (or "
          "run --simulate ... --observer-params)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m experiment``: one subparser per subcommand."""
    parser = argparse.ArgumentParser(prog="python -m experiment",
                                     description="The gloss x depth session app.")
    parser.add_argument("--design", help="a design.toml (default: the shipped one)")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("plan", help="make (or show) a participant's trial plan")
    p.add_argument("--participant", required=True, help="participant id, e.g. P01")
    p.add_argument("--data", "--data-dir", dest="data",
                   help=f"data folder (default: ${DATA_ENV}; required without it)")
    p.set_defaults(func=_cmd_plan)

    r = sub.add_parser("run", help="run or resume a session (a dialog asks for what is missing)")
    r.add_argument("--participant", help="participant id, e.g. P01")
    r.add_argument("--session", help="session number (1..n_sessions of the design)")
    r.add_argument("--stimuli", help="the stimulus manifest.csv (python -m stimuli render)")
    r.add_argument("--calibration", help="calibration.json (python -m calibration run)")
    r.add_argument("--data", help=f"data folder (default: ${DATA_ENV}; required without it)")
    r.add_argument("--max-calibration-age-days", type=float, default=30.0,
                   help="refuse a calibration older than this (default 30 days)")
    r.add_argument("--accept-calibration-mismatch", action="store_true",
                   help="run although the stimuli were corrected for another calibration "
                        "(recorded in the log)")
    r.add_argument("--accept-unverified-resume", action="store_true",
                   help="resume a session whose record of its stimuli and calibration "
                        "(_runs.jsonl, run logs) is lost, once you have checked they are the "
                        "ones it started with (recorded in the log)")
    r.add_argument("--fullscr", action="store_true",
                   help="full screen (the lab CRT; the screen must be at the design's resolution)")
    r.add_argument("--fast", action="store_true",
                   help="do not wait for the vertical blank (headless runs only)")
    r.add_argument("--simulate", choices=["ideal", "humanlike"],
                   help="a simulated observer answers through X11 input events (XTEST)")
    r.add_argument("--observer-params", help="observers.toml to use with --simulate")
    r.add_argument("--seed", type=_seed, help="seed of the simulated observer (default: from "
                                            "the participant id)")
    r.add_argument("--screenshot", help="save the first answered trial screen (back buffer) as "
                                        "this PNG")
    r.add_argument("--simulate-quit-at", type=int, metavar="TRIAL",
                   help="(tests) the simulated observer presses Esc twice at this trial")
    r.add_argument("--simulate-early-space", type=float, default=0.0, metavar="P",
                   help="(tests) chance per trial of pressing space with one slider set")
    r.set_defaults(func=_cmd_run)

    st = sub.add_parser("status", help="how far a participant's sessions are")
    st.add_argument("--participant", required=True)
    st.add_argument("--data", help=f"data folder (default: ${DATA_ENV}; required without it)")
    st.set_defaults(func=_cmd_status)

    s = sub.add_parser("simulate", help="write simulated session CSVs (observer model, no app)")
    s.add_argument("--observer", choices=["ideal", "humanlike"], required=True)
    s.add_argument("--participants", nargs="+", required=True, help="participant ids")
    s.add_argument("--data", required=True,
                   help="data folder (writes DATA/sessions/); not the lab's data: the analysis "
                        "report flags simulated participants")
    s.add_argument("--seed", type=_seed, default=1)
    s.add_argument("--observer-params", help="observers.toml (default: the shipped one)")
    s.set_defaults(func=_cmd_simulate)

    f = sub.add_parser("fit-observer", help="fit the simulated observers to session CSVs (a "
                                            "pilot) and write an observers.toml")
    f.add_argument("sessions", nargs="+", metavar="SESSIONS",
                   help="a data folder (its sessions/*.csv), a folder of session CSVs, or CSVs")
    f.add_argument("--out", required=True, help="the observers.toml to write (never overwritten)")
    f.add_argument("--kind", choices=["humanlike", "ideal"], default="humanlike",
                   help="the kind the file is meant for (both are fitted; default humanlike)")
    f.add_argument("--study", help="another lab's study.toml (its folder is SESSIONS): fit the "
                                   "one-response rating observer (protocol.md, 'Another lab's "
                                   "study')")
    f.add_argument("--participants", nargs="+", help="with --study: fit only these participants")
    f.set_defaults(func=_cmd_fit_observer)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from experiment.signals import SessionSignal, ending_signals

    try:
        # From here, not only once the session runs: a SIGTERM while PsychoPy loads is said too.
        with ending_signals() if args.command == "run" else contextlib.nullcontext():
            return args.func(args)
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except DesignError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except SessionSignal as exc:
        print(f"ended by {exc.name} before the session started: no trial was shown or recorded; "
              "run the same command to start it", file=sys.stderr)
        return 128 + exc.signum


if __name__ == "__main__":
    sys.exit(main())
