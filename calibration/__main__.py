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
            tmp = f"{args.port_file}.tmp"
            with open(tmp, "w") as fh:
                fh.write(fake.port + "\n")
            import os

            os.replace(tmp, args.port_file)
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


def _settings(args):
    from calibration.procedure import ProcedureSettings

    cal_id = args.calibration_id or datetime.now(UTC).strftime("cal-%Y%m%dT%H%M%SZ")
    kw = {"calibration_id": cal_id, "device": args.device, "seed": args.seed,
          "n_levels": args.levels, "uniformity_levels": args.uniformity_levels,
          "n_repeats": args.repeats, "grid": args.grid, "n_validation": args.validation}
    kw["settle_s"] = 0.05 if args.fast and args.settle_s is None else (args.settle_s or 0.5)
    return ProcedureSettings(**kw)


def _cmd_run(args) -> int:
    from calibration.errors import CalibrationError
    from calibration.run import run_calibration
    from studydesign import load_design

    design = load_design(args.design) if args.design else load_design()
    timeout_s = args.timeout_s or (2.0 if args.fast else 30.0)
    try:
        _cal, paths = run_calibration(
            design, device=args.device, port=args.port, out_dir=args.out,
            settings=_settings(args), width_cm=args.width_cm, monitor_name=args.monitor_name,
            timeout_s=timeout_s, retries=args.retries, fullscr=not args.windowed,
            refresh_hz=args.refresh_hz, sim_aim=args.sim_aim)
    except CalibrationError as exc:
        print(f"calibration stopped: {exc}", file=sys.stderr)
        return 2
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


def _cmd_fit(args) -> int:
    from calibration.errors import CalibrationError
    from calibration.run import refit

    try:
        _, paths = refit(args.out)
    except CalibrationError as exc:
        print(f"fit failed: {exc}", file=sys.stderr)
        return 1
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


def _cmd_default(args) -> int:
    from calibration.record import default_calibration, save_calibration
    from studydesign import load_design

    design = load_design(args.design) if args.design else load_design()
    print(save_calibration(default_calibration(design), args.out))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m calibration",
                                     description="Calibrate the display.")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("ports", help="list serial ports")
    p.set_defaults(func=_cmd_ports)

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

    p = sub.add_parser("run", help="measure, fit and write a calibration (resumes in --out)")
    p.add_argument("--device", choices=["pr655", "pr650", "ls100"], required=True)
    p.add_argument("--port", required=True, help="serial port (python -m calibration ports)")
    p.add_argument("--out", required=True, help="calibration folder (a rerun resumes)")
    p.add_argument("--design", default=None, help="study design TOML (default: shipped)")
    p.add_argument("--calibration-id", default=None,
                   help="default cal-<UTC time>; a resumed run keeps its stored id")
    p.add_argument("--levels", type=int, default=17, help="levels at the centre")
    p.add_argument("--uniformity-levels", type=int, default=5,
                   help="levels at the other grid positions")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--grid", type=int, default=3, help="positions per side (1: centre only)")
    p.add_argument("--validation", type=int, default=9,
                   help="corrected patches measured after the fit (0: none)")
    p.add_argument("--settle-s", type=float, default=None,
                   help="wait after each patch appears (default 0.5 s; 0.05 s with --fast)")
    p.add_argument("--timeout-s", type=float, default=None,
                   help="reply timeout (default 30 s; 2 s with --fast)")
    p.add_argument("--retries", type=int, default=2, help="retries after a timeout")
    p.add_argument("--fast", action="store_true", help="short settling and timeouts (tests)")
    p.add_argument("--seed", type=int, default=20261122, help="seed of the patch order")
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
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("fit", help="fit again from a calibration folder's readings")
    p.add_argument("--out", required=True)
    p.set_defaults(func=_cmd_fit)

    p = sub.add_parser("default", help="write the default (unmeasured) calibration JSON")
    p.add_argument("--out", required=True)
    p.add_argument("--design", default=None)
    p.set_defaults(func=_cmd_default)

    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
