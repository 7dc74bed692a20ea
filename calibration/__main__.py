"""``python -m calibration``: calibrate the CRT with a photometer."""

from __future__ import annotations

import argparse
import sys
from datetime import UTC, datetime


def _cmd_ports(args) -> int:
    from calibration.ports import available_ports

    ports = available_ports()
    if not ports:
        print("no serial ports found; check the photometer's cable and power, and that the "
              "USB-serial adapter's driver is loaded (dmesg)")
        return 0
    for p in ports:
        print(f"{p['device']}\t{p['description']}\t{p['hwid']}")
    return 0


def _cmd_fake(args) -> int:
    import numpy as np

    from calibration.crt import load_crt
    from calibration.fake_instrument import FakePhotometer, X11Screen, parse_faults

    crt = load_crt(args.display)
    faults = parse_faults(args.fault)
    screen = X11Screen(aim_file=args.aim)
    with FakePhotometer(args.device, crt, screen, np.random.default_rng(args.seed),
                        faults=faults, measure_s=args.measure_s) as fake:
        if args.port_file:
            from labfiles import atomic_write_text

            atomic_write_text(args.port_file, fake.port + "\n")
        print(fake.port, flush=True)
        print(f"simulated {args.device} on {fake.port} (seed {args.seed}); screen "
              f"{screen.width_px} x {screen.height_px} px; Ctrl-C stops", file=sys.stderr,
              flush=True)
        try:
            fake.wait()
        except KeyboardInterrupt:
            pass
        if fake.unplugged.is_set():
            print(f"simulated unplug after {fake.n_measurements} measurements", file=sys.stderr)
    screen.close()
    return 0


#: A new run's settings where no option is given (ProcedureSettings holds the others).
RUN_DEFAULTS = {"n_levels": 17, "uniformity_levels": 5, "n_repeats": 2, "grid": 3,
                "n_validation": 9, "seed": 20261122}


def _settings(args, *, out, defaults, default_id):
    """Settings from the options given; a resumed folder supplies those not given."""
    from calibration.procedure import settings_from_options

    options = {"calibration_id": args.calibration_id, "device": args.device, "seed": args.seed,
               "n_levels": args.levels, "uniformity_levels": args.uniformity_levels,
               "n_repeats": args.repeats, "grid": args.grid,
               "n_validation": getattr(args, "validation", None)}
    if args.settle_s is not None:
        settle_s = args.settle_s
    else:
        settle_s = 0.05 if args.fast else 0.5
    base = defaults | {"calibration_id": default_id(), "settle_s": settle_s}
    settings, given = settings_from_options(options, out, defaults=base)
    # settle_s only changes the waiting, not what is measured: the one given now applies.
    from dataclasses import replace

    return replace(settings, settle_s=settle_s), given


def _interrupted(out, what: str) -> int:
    """The message for Ctrl-C: what was kept, how to resume."""
    from pathlib import Path

    from calibration.readings import read_readings

    kept = []
    for name in ("warmup.csv", "readings.csv", "validation.csv"):
        path = Path(out) / name
        if not path.is_file():  # a file this command never writes, or nothing measured yet
            continue
        try:
            kept.append(f"{read_readings(path, own_file=False).n_rows} readings in {path}")
        except (ValueError, OSError):
            kept.append(str(path))
    print(f"\n{what} stopped (Ctrl-C). Kept: {'; '.join(kept) or 'nothing measured yet'}. Run "
          "the same command again to resume (only what is missing is measured).",
          file=sys.stderr)
    return 130


def _measure(what: str, out, work):
    """``(work(), None)``, or ``(None, exit code)`` after saying why a measuring command
    stopped: a lab error or a write that failed (2; the readings so far are kept), Ctrl-C (130,
    :func:`_interrupted`)."""
    from calibration.errors import CalibrationError
    from labfiles import LabFileError

    try:
        return work(), None
    except (CalibrationError, LabFileError) as exc:
        print(f"{what} stopped: {exc}", file=sys.stderr)
        return None, 2
    except OSError as exc:
        print(f"{what} stopped: {exc}; check that --out is writable and the disk has space "
              "(readings so far are kept)", file=sys.stderr)
        return None, 2
    except KeyboardInterrupt:
        return None, _interrupted(out, what)


def _cmd_run(args) -> int:
    from calibration.run import run_calibration
    from studydesign import load_design

    timeout_s = args.timeout_s or (2.0 if args.fast else 30.0)

    def work():
        design = load_design(args.design) if args.design else load_design()
        settings, given = _settings(
            args, out=args.out, defaults=RUN_DEFAULTS,
            default_id=lambda: datetime.now(UTC).strftime("cal-%Y%m%dT%H%M%SZ"))
        return run_calibration(
            design, device=args.device, port=args.port, out_dir=args.out,
            settings=settings, width_cm=args.width_cm, monitor_name=args.monitor_name,
            timeout_s=timeout_s, retries=args.retries, fullscr=not args.windowed,
            refresh_hz=args.refresh_hz, sim_aim=args.sim_aim, given=given,
            force_profile=args.force)
    done, rc = _measure("calibration", args.out, work)
    if rc is not None:
        return rc
    _cal, paths = done
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


def _parse_position(text):
    from calibration.errors import CalibrationError

    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise CalibrationError(f"--position {text!r}: write X,Y in norm units, e.g. 0,0 or "
                               "-0.6,0.6") from None
    return x, y


def _parse_dac_bits(text):
    """``--dac-bits``: 8 by default, an int in 1..16, or ``none`` (levels as given)."""
    from calibration.errors import CalibrationError
    from calibration.gamma import DAC_BITS

    if text is None:
        return DAC_BITS
    if str(text).strip().lower() == "none":
        return None
    try:
        bits = int(text)
    except ValueError:
        bits = 0
    if not 1 <= bits <= 16:
        raise CalibrationError(f"--dac-bits {text!r}: write the bits per gun of the display's "
                               "output (8 for a frame buffer, 10 for a 10-bit lookup table) or "
                               "none to fit the levels as given")
    return bits


def _written(what: str, source: str, out, work) -> int:
    """Run ``work() -> (calibration, paths)`` of ``fit`` or ``import-psychopy`` and print the
    files it wrote; a lab error, a failed read or write (1) or Ctrl-C (130) is one line.

    ``source`` names what was read (``"the readings"``), ``out`` the folder written."""
    from calibration.errors import CalibrationError
    from labfiles import LabFileError

    try:
        _, paths = work()
    except (CalibrationError, LabFileError) as exc:
        print(f"{what} failed: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"{what} failed: {exc}; check that {source} can be read and --out is writable",
              file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"\n{what} stopped (Ctrl-C). Every file in {out} is whole (each is written at "
              f"once); {source} left untouched. Run the same command again to {what}.",
              file=sys.stderr)
        return 130
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


def _cmd_fit(args) -> int:
    from calibration.errors import CalibrationError
    from calibration.readings import parse_level_scale
    from calibration.run import fit_readings_file, load_display_file, refit
    from studydesign import load_design

    def work():
        if args.readings is None:
            extra = [o for o, v in (("--level-scale", args.level_scale),
                                    ("--position", args.position),
                                    ("--display", args.display),
                                    ("--calibration-id", args.calibration_id),
                                    ("--measured-utc", args.measured_utc),
                                    ("--dac-bits", args.dac_bits),
                                    ("--floor-cd-m2", args.floor_cd_m2)) if v is not None]
            if extra:
                raise CalibrationError(f"{', '.join(extra)} apply to a readings file: "
                                       "`python -m calibration fit READINGS.csv --out DIR ...`")
            return refit(args.out, force_profile=args.force)
        design = load_design(args.design) if args.design else load_design()
        return fit_readings_file(
            args.readings, args.out, design,
            level_scale=parse_level_scale(args.level_scale or "0-1"),
            position=_parse_position(args.position) if args.position else None,
            calibration_id=args.calibration_id,
            display=load_display_file(args.display) if args.display else None,
            measured_utc=args.measured_utc,
            dac_bits=_parse_dac_bits(args.dac_bits), floor_cd_m2=args.floor_cd_m2,
            force_profile=args.force)

    return _written("fit", "the readings", args.out, work)


def _cmd_import_psychopy(args) -> int:
    from calibration.psychopy_import import import_psychopy_profile
    from studydesign import load_design

    def work():
        design = load_design(args.design) if args.design else load_design()
        return import_psychopy_profile(
            args.profile, args.out, design, calib_name=args.psychopy_calibration,
            calibration_id=args.calibration_id, measured_utc=args.measured_utc,
            force_profile=args.force)

    return _written("import", "the profile", args.out, work)


def _cmd_check(args) -> int:
    from calibration.check import CHECK_DEFAULTS, WarmupRule, default_check_id, run_check
    from calibration.record import load_calibration

    timeout_s = args.timeout_s or (2.0 if args.fast else 30.0)

    def work():
        cal = load_calibration(args.calibration)
        settings, given = _settings(args, out=args.out, defaults=CHECK_DEFAULTS,
                                    default_id=lambda: default_check_id(cal.calibration_id))
        rule = WarmupRule(interval_s=args.warmup_interval_s, window_s=args.warmup_window_s,
                          tolerance_pct=args.warmup_tolerance_pct, max_s=args.warmup_max_s)
        return run_check(args.calibration, device=args.device, port=args.port,
                         out_dir=args.out, settings=settings, rule=rule,
                         tolerance_pct=args.tolerance_pct,
                         tolerance_cd_m2=args.tolerance_cd_m2, timeout_s=timeout_s,
                         retries=args.retries, fullscr=not args.windowed,
                         sim_aim=args.sim_aim, given=given)
    result, rc = _measure("check", args.out, work)
    if rc is not None:
        return rc
    print(f"check: {args.out}/check.json")
    return 0 if result["passed"] else 1


def _cmd_default(args) -> int:
    from pathlib import Path

    from calibration.record import default_calibration, load_calibration, save_calibration
    from studydesign import load_design

    design = load_design(args.design) if args.design else load_design()
    out = Path(args.out)
    if out.is_dir():
        print(f"error: --out {out} is a folder; name the file to write, e.g. --out "
              f"{out / 'default-calibration.json'}", file=sys.stderr)
        return 1
    if out.exists() and not args.force:
        try:
            held = f"calibration {load_calibration(out).calibration_id!r}"
        except ValueError:
            held = "a file"
        print(f"error: {out} exists ({held}) and would be replaced by the default, unmeasured "
              "curve; choose another --out, or add --force to replace it", file=sys.stderr)
        return 1
    try:
        print(save_calibration(default_calibration(design), out))
    except OSError as exc:
        print(f"error: cannot write {out} ({exc.strerror}); choose a writable --out",
              file=sys.stderr)
        return 1
    return 0


def _patch_options(p, defaults: dict, default_id: str) -> None:
    """Options that set the patches (None when not given: a resumed folder keeps its own)."""
    p.add_argument("--calibration-id", default=None,
                   help=f"default {default_id}; a resumed run keeps its stored id")
    p.add_argument("--levels", type=int, default=None,
                   help=f"levels at the centre (default {defaults['n_levels']})")
    p.add_argument("--uniformity-levels", type=int, default=None,
                   help=f"levels at the other positions (default {defaults['uniformity_levels']})")
    p.add_argument("--repeats", type=int, default=None,
                   help=f"readings per patch (default {defaults['n_repeats']})")
    p.add_argument("--grid", type=int, default=None,
                   help=f"positions per side (1: centre only; default {defaults['grid']})")
    p.add_argument("--seed", type=int, default=None,
                   help=f"seed of the patch order (default {defaults['seed']})")
    p.add_argument("--settle-s", type=float, default=None,
                   help="wait after each patch appears (default 0.5 s; 0.05 s with --fast)")
    p.add_argument("--timeout-s", type=float, default=None,
                   help="reply timeout (default 30 s; 2 s with --fast)")
    p.add_argument("--retries", type=int, default=2, help="retries after a timeout")
    p.add_argument("--fast", action="store_true", help="short settling and timeouts (tests)")


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"warning: {message}", file=sys.stderr if file is None else file)


def _add_ports(sub) -> None:
    p = sub.add_parser("ports", help="list serial ports")
    p.set_defaults(func=_cmd_ports)


def _add_fake_photometer(sub) -> None:
    p = sub.add_parser("fake-photometer",
                       help="simulated photometer on a pseudo-terminal (prints the port path)")
    p.add_argument("--device", choices=["pr655", "pr650", "ls100"], required=True)
    p.add_argument("--display", default=None,
                   help="simulated CRT parameters (TOML with a [crt] table; default: shipped "
                        "calibration/crt.toml)")
    p.add_argument("--aim", default=None,
                   help="file the procedure's --sim-aim writes: where the photometer points")
    p.add_argument("--seed", type=int, default=1, help="seed of the measurement noise")
    p.add_argument("--measure-s", type=float, default=0.05,
                   help="seconds one measurement takes")
    p.add_argument("--fault", action="append", default=[],
                   help="KIND:WHEN, KIND in timeout, garbled, out_of_range, saturated, unplug; "
                        "WHEN a measurement number, N-M, a comma list or all (repeatable)")
    p.add_argument("--port-file", default=None, help="also write the port path to this file")
    p.set_defaults(func=_cmd_fake)


def _add_run(sub) -> None:
    p = sub.add_parser("run", help="measure, fit and write a calibration (resumes in --out)")
    p.add_argument("--device", choices=["pr655", "pr650", "ls100"], required=True)
    p.add_argument("--port", required=True, help="serial port (python -m calibration ports)")
    p.add_argument("--out", required=True, help="calibration folder (a rerun resumes)")
    p.add_argument("--design", default=None, help="study design TOML (default: shipped)")
    _patch_options(p, RUN_DEFAULTS, "cal-<UTC time>")
    p.add_argument("--validation", type=int, default=None,
                   help="corrected patches measured after the fit (0: none; default 9)")
    p.add_argument("--width-cm", type=float, default=None,
                   help="visible picture width, measured with a ruler")
    p.add_argument("--monitor-name", default="glossdepth-crt",
                   help="name of the PsychoPy monitor profile written")
    p.add_argument("--windowed", action="store_true", help="not full screen (debugging)")
    p.add_argument("--refresh-hz", type=float, default=None,
                   help="record this refresh rate instead of measuring it, for a display that "
                        "does not sync to the vertical blank (a virtual X display); flagged in "
                        "the record")
    p.add_argument("--sim-aim", default=None,
                   help="simulation only: write the photometer's aim here for the fake "
                        "instrument instead of asking the experimenter")
    _force_profile_option(p)
    p.set_defaults(func=_cmd_run)


def _add_fit(sub) -> None:
    p = sub.add_parser(
        "fit", help="fit a readings file (any tool's) into --out, or refit a calibration folder",
        description="`fit READINGS.csv --out DIR` fits a readings file alone: columns level and "
                    "luminance_cd_m2, optional x_norm, y_norm, repeat, timestamp_utc, "
                    "calibration_id, device, raw_reply (protocol.md section 3). `fit --out DIR` "
                    "refits a calibration folder from its readings.")
    p.add_argument("readings", nargs="?", default=None,
                   help="readings CSV (omit to refit the folder --out)")
    p.add_argument("--out", required=True, help="calibration folder written (or refitted)")
    p.add_argument("--level-scale", default=None,
                   help="drive value of full white in the file: 0-1 (default), 0-255, 0-1023 "
                        "or any maximum")
    p.add_argument("--position", default=None,
                   help="X,Y: fit only the readings at this position (norm units)")
    p.add_argument("--calibration-id", default=None,
                   help="the file's calibration to fit (needed when it holds several); also the "
                        "new calibration's id (default: the file's id, else import-<file name>)")
    p.add_argument("--display", default=None,
                   help="TOML file whose [display] table gives width_cm, resolution_px, "
                        "distance_cm, refresh_hz, monitor_name, device (default: the design's "
                        "values and a 32 cm width, with warnings)")
    p.add_argument("--measured-utc", default=None,
                   help="when the readings were taken (ISO 8601 UTC), for a file without "
                        "timestamp_utc: the calibration's age counts from it")
    p.add_argument("--dac-bits", default=None,
                   help="bits per gun of the display's output: levels are rounded to its grid, "
                        "the drive the display showed (default 8, the frame buffer); 'none' "
                        "fits the levels as given, for a display behind a finer lookup table "
                        "(e.g. Psychtoolbox's LoadNormalizedGammaTable on a 10-bit DAC)")
    p.add_argument("--floor-cd-m2", type=float, default=None,
                   help="the photometer's floor, cd/m^2 (its specification's lowest reading): "
                        "readings at or below it are fitted as censored (default: 2 noise SDs, "
                        "0.2 %% of white without repeated readings)")
    p.add_argument("--design", default=None, help="study design TOML (default: shipped)")
    _force_profile_option(p)
    p.set_defaults(func=_cmd_fit)


def _force_profile_option(p) -> None:
    p.add_argument("--force", action="store_true",
                   help="add this calibration to a PsychoPy profile monitors/<name>.json that "
                        "holds other calibrations (theirs are kept); without it such a profile "
                        "is refused and left unchanged")


def _add_import_psychopy(sub) -> None:
    p = sub.add_parser(
        "import-psychopy", help="a PsychoPy Monitor Center profile as a calibration in --out",
        description="Reads a PsychoPy monitor profile with PsychoPy: its readings (lumsPre at "
                    "levelsPre) are fitted as any readings; a profile without readings keeps "
                    "its gamma grid's curve, not refitted. Dated by the profile's calibDate. "
                    "Writes what `fit` writes (protocol.md section 3).")
    p.add_argument("profile", help="monitor name in PsychoPy's monitor folder, or NAME.json")
    p.add_argument("--out", required=True, help="calibration folder written (a new one)")
    p.add_argument("--psychopy-calibration", default=None,
                   help="the profile's calibration to import (default: PsychoPy's current one, "
                        "the last by name)")
    p.add_argument("--calibration-id", default=None,
                   help="the new calibration's id (default psychopy-<monitor>-<calibration>)")
    p.add_argument("--measured-utc", default=None,
                   help="when it was measured (ISO 8601 UTC), for a profile without calibDate")
    p.add_argument("--design", default=None, help="study design TOML (default: shipped)")
    _force_profile_option(p)
    p.set_defaults(func=_cmd_import_psychopy)


def _add_check(sub) -> None:
    from calibration.check import CHECK_DEFAULTS

    p = sub.add_parser(
        "check", help="measure warm-up drift and a few patches against a calibration (no refit)")
    p.add_argument("--calibration", required=True,
                   help="calibration.json (or its folder) to check")
    p.add_argument("--device", choices=["pr655", "pr650", "ls100"], required=True)
    p.add_argument("--port", required=True, help="serial port (python -m calibration ports)")
    p.add_argument("--out", required=True, help="check folder (a rerun resumes)")
    _patch_options(p, CHECK_DEFAULTS, "<checked id>-check-<UTC time>")
    p.add_argument("--tolerance-pct", type=float, default=3.0,
                   help="a patch passes within this %% of the prediction (default 3)")
    p.add_argument("--tolerance-cd-m2", type=float, default=0.05,
                   help="... or within this many cd/m^2 (default 0.05; the darkest patches)")
    p.add_argument("--warmup-interval-s", type=float, default=10.0,
                   help="time between white readings during warm-up (default 10 s)")
    p.add_argument("--warmup-window-s", type=float, default=120.0,
                   help="stable when the mean of the last window differs from the window before "
                        "by <= --warmup-tolerance-pct (default 120 s)")
    p.add_argument("--warmup-tolerance-pct", type=float, default=0.5, help="default 0.5 %%")
    p.add_argument("--warmup-max-s", type=float, default=3600.0,
                   help="give up waiting after this long and measure anyway (default 3600 s)")
    p.add_argument("--windowed", action="store_true", help="not full screen (debugging)")
    p.add_argument("--sim-aim", default=None, help="simulation only (see `run --sim-aim`)")
    p.set_defaults(func=_cmd_check)


def _add_default(sub) -> None:
    p = sub.add_parser("default", help="write the default (unmeasured) calibration JSON")
    p.add_argument("--out", required=True, help="the JSON file to write (never replaced "
                                                "without --force)")
    p.add_argument("--force", action="store_true", help="replace an existing --out")
    p.add_argument("--design", default=None)
    p.set_defaults(func=_cmd_default)


#: One function per subcommand, each adding its parser and handler (``func``); in help order.
_SUBCOMMANDS = (_add_ports, _add_fake_photometer, _add_run, _add_fit, _add_import_psychopy,
                _add_check, _add_default)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m calibration``: one subparser per subcommand."""
    parser = argparse.ArgumentParser(prog="python -m calibration",
                                     description="Calibrate the display.")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in _SUBCOMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the subcommand's handler; returns its exit code."""
    args = build_parser().parse_args(argv)
    import warnings

    warnings.showwarning = _show_warning  # one line per warning, no source line
    from calibration.errors import CalibrationError

    if getattr(args, "out", None) is not None and not str(args.out).strip():
        print("error: --out is empty: give it a folder name (an empty name would write into "
              "the current folder)", file=sys.stderr)
        return 2
    try:
        return args.func(args)
    except CalibrationError as exc:  # a handler's own refusal (e.g. a bad --fault): one line
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
