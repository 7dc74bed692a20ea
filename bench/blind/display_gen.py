"""Blind display generator: a display and a photometer, written from a physical description alone.

Written by helper "blind" without reading the gap diagnosis (analysis/gap, analysis/gapbench,
protocol 7.2 beyond its command lines). Plain NumPy; nothing of the project is imported, so what
this file writes is data the diagnosis did not make.

The display (one per seed)
--------------------------
    L(v, x, y, t) = offset(t) + gain * w(t) * s(x, y) * v ** gamma          [cd/m^2]

    v          drive level in [0, 1] (written as given: fit with ``--dac-bits none``)
    offset     black + reflected room light, U(0.1, 1.0) cd/m^2
    gain       white above black, U(80, 200) cd/m^2
    gamma      U(1.8, 2.6)
    s(x, y)    1 - k r^2: brightest at the centre, falling with the square of the physical
               distance r from it (r = 1 at the screen's corner; a 4:3 screen, so a norm-unit
               step in x is 4/3 of one in y). k is drawn so that the measured corner patches
               (x, y = +-0.6 norm, r^2 = 0.36) sit 2-6 % below the centre.
    w(t)       the display's slow gain wander after warm-up: an Ornstein-Uhlenbeck process,
               stationary SD U(0.1, 0.3) %, correlation time 10 min, ONE process running through
               both runs (calibration and check sample the same display at different times)
    offset(t)  the room light on the screen wanders the same way, SD 2 % of the offset

Why these between-run changes: a warmed-up CRT or LCD backlight is stable to a few tenths of a %
over tens of minutes (CRT high-voltage regulation, LCD backlight thermal drift); a gain wander of
0.1-0.3 % SD with a 10-min correlation time puts two runs ~30 min apart a fraction of a % apart,
while two repeats seconds apart see almost none of it. Room light seen in a dark screen moves by a
few % (people moving, doors); 2 % of a 0.1-1 cd/m^2 offset is 0.002-0.02 cd/m^2.

The meter
---------
    reading = L (1 + 0.004 e1) + 0.01 e2,   e1, e2 ~ N(0, 1) independent   [cd/m^2]

written with 4 significant digits (as a PR-650/670 reports), and 0 when the reading falls below
the meter's sensitivity floor (drawn per seed, U(0.05, 0.4) cd/m^2 for the PR-650-like meter of
most cases). A reading takes 4 s (PR-650: 3-8 s per measurement).

The runs
--------
17 levels (0, 1/16, ..., 1) x 3 x 3 positions (x, y in -0.6, 0, 0.6 norm; centre first, then
row by row) x 2 repeats read back to back; at each position the levels in a fresh random order.
The check run begins 5-20 min after the calibration run ended (``clean`` and the effect cases).

Cases (each writes calib.csv, check.csv, truth.json)
----------------------------------------------------
clean          the same display, the check run minutes later: only the wander above.
repeat_pass    a second pass right after the first (30-120 s later), 8 levels, a dark display
               (offset 0.05-0.2 cd/m^2) read by a PR-670 whose floor lies 1.5-3x above its
               black, so black reads exactly 0 in both passes (the NEC case of issue 38); the
               same meter noise; only the wander. Expected: no gap.
gain           the check's gain is 10-30 % higher or lower (a brightness control touched, a
               backlight ageing step). Expected name: a gain change.
black_offset   the check's offset is raised by 0.5-2 cd/m^2 (room light on, a reflection, the
               brightness/black-level control). Expected name: a black/offset change.
warmup         the check run starts at power-on: gain * (1 - d exp(-t / tau)), d U(5, 15) %,
               tau U(3, 10) min, t from the first check reading (timestamps say when).
               Expected name: warm-up drift.
uniformity     the check's centre-to-corner falloff k grows so the measured corners sit a further
               4-10 % below the centre (the display moved near a magnet / re-seated).
               Expected name: a uniformity change.

Usage
-----
    python bench/blind/display_gen.py --case clean --seed 3 --out /tmp/disp/clean-3
    python -m calibration fit /tmp/disp/clean-3/calib.csv --out /tmp/disp/clean-3/CAL --dac-bits none
    python -m analysis gap diagnose --layer display --real /tmp/disp/clean-3/check.csv \
        --sim /tmp/disp/clean-3/CAL --out /tmp/disp/clean-3/REPORT
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

CASES = ("clean", "repeat_pass", "gain", "black_offset", "warmup", "uniformity")
#: What the diagnosis should say for each case: "none" (no gap) or the effect's name.
#: Catalogue names as the diagnosis's output (diagnosis.json "ranking") lists them.
EXPECTED = {"clean": "none", "repeat_pass": "none", "gain": "gain_change",
            "black_offset": "black_offset", "warmup": "warmup_drift",
            "uniformity": "nonuniformity"}

COLUMNS = ("calibration_id", "timestamp_utc", "device", "x_norm", "y_norm", "level", "repeat",
           "luminance_cd_m2", "raw_reply")
GRID_NORM = (-0.6, 0.0, 0.6)
SECONDS_PER_READING = 4.0
WANDER_TAU_S = 600.0
NOISE_REL = 0.004
NOISE_ABS_CD_M2 = 0.01
START_UTC = datetime(2026, 3, 2, 9, 0, 0, tzinfo=UTC)


def positions():
    """The 3 x 3 grid in norm units, centre first, then row by row (top row first)."""
    grid = [(x, y) for y in GRID_NORM[::-1] for x in GRID_NORM]
    grid.remove((0.0, 0.0))
    return [(0.0, 0.0), *grid]


def r2_physical(x, y):
    """Squared distance from the centre, 1 at the corner of a 4:3 screen (norm units in)."""
    return ((4.0 * np.asarray(x)) ** 2 + (3.0 * np.asarray(y)) ** 2) / 25.0


def draw_display(rng):
    """One display's parameters (see the module docstring)."""
    corner_drop = rng.uniform(0.02, 0.06)  # at the measured corner, r^2 = 0.36
    return {
        "offset_cd_m2": float(rng.uniform(0.1, 1.0)),
        "gain_cd_m2": float(rng.uniform(80.0, 200.0)),
        "gamma": float(rng.uniform(1.8, 2.6)),
        "falloff_k": float(corner_drop / r2_physical(0.6, 0.6)),
        "wander_sd": float(rng.uniform(0.001, 0.003)),
        "offset_wander_sd": 0.02,
    }


def schedule(rng, levels, t0_s, n_repeats=2):
    """Rows (time_s, x, y, level, repeat) of one run in the order measured."""
    rows, t = [], t0_s
    for x, y in positions():
        for v in rng.permutation(levels):
            for rep in range(n_repeats):
                rows.append((t, x, y, float(v), rep))
                t += SECONDS_PER_READING
    return np.array(rows, float)


def ou_path(rng, times_s, sd, tau_s):
    """An Ornstein-Uhlenbeck process (mean 0, stationary SD ``sd``) at increasing times."""
    out = np.empty(len(times_s))
    x = rng.normal(0.0, sd)
    prev = times_s[0]
    for i, t in enumerate(times_s):
        rho = np.exp(-(t - prev) / tau_s)
        x = rho * x + np.sqrt(1.0 - rho * rho) * sd * rng.normal()
        out[i] = x
        prev = t
    return out


def luminance(disp, v, x, y, *, wander, offset_wander, gain_factor=1.0, offset_add=0.0,
              falloff_k=None, warm=None):
    """True luminance of each reading, cd/m^2."""
    k = disp["falloff_k"] if falloff_k is None else falloff_k
    s = 1.0 - k * r2_physical(x, y)
    g = disp["gain_cd_m2"] * gain_factor * (1.0 + wander) * s
    if warm is not None:
        g = g * warm
    off = disp["offset_cd_m2"] * (1.0 + offset_wander) + offset_add
    return off + g * np.power(v, disp["gamma"])


def meter(rng, lum, floor_cd_m2):
    """Readings as the meter reports them: noise, 4 significant digits, 0 below its floor."""
    read = lum * (1.0 + NOISE_REL * rng.normal(size=lum.shape)) \
        + NOISE_ABS_CD_M2 * rng.normal(size=lum.shape)
    read = np.where(read < floor_cd_m2, 0.0, read)
    return np.array([float(f"{r:.4g}") for r in read])


def write_csv(path, cal_id, device, sched, readings):
    lines = [",".join(COLUMNS)]
    for (t, x, y, v, rep), lum in zip(sched, readings, strict=True):
        stamp = (START_UTC + timedelta(seconds=float(t))).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        lines.append(f"{cal_id},{stamp},{device},{x:g},{y:g},{v:.6f},{int(rep)},{lum:.4g},")
    tmp = Path(str(path) + ".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)


def generate(case, seed, out):
    """Write ``out``/calib.csv, check.csv and truth.json for one case and seed."""
    if case not in CASES:
        raise ValueError(f"--case {case!r}: choose one of {', '.join(CASES)}")
    # One stream per (case, seed): the same seed gives the same display in every case.
    rng = np.random.default_rng([seed, 7919])
    disp = draw_display(rng)
    rng_case = np.random.default_rng([seed, CASES.index(case), 104729])
    device, floor = "PR-650", float(rng.uniform(0.05, 0.4))
    levels = np.linspace(0.0, 1.0, 17)
    gap_s = float(rng_case.uniform(300.0, 1200.0))
    if case == "repeat_pass":
        levels = np.linspace(0.0, 1.0, 8)
        device = "PR-670"
        # A precise meter whose floor still lies above this display's black (a dark LCD).
        disp["offset_cd_m2"] = float(rng_case.uniform(0.05, 0.2))
        floor = float(disp["offset_cd_m2"] * rng_case.uniform(1.5, 3.0))
        gap_s = float(rng_case.uniform(30.0, 120.0))
    cal = schedule(rng_case, levels, 0.0)
    chk = schedule(rng_case, levels, cal[-1, 0] + SECONDS_PER_READING + gap_s)
    times = np.concatenate([cal[:, 0], chk[:, 0]])
    wander = ou_path(rng_case, times, disp["wander_sd"], WANDER_TAU_S)
    off_w = ou_path(rng_case, times, disp["offset_wander_sd"], WANDER_TAU_S)
    n = len(cal)
    effect = {}
    kw = {}
    if case == "gain":
        f = rng_case.uniform(0.10, 0.30) * rng_case.choice([-1.0, 1.0])
        kw["gain_factor"] = 1.0 + f
        effect = {"gain_change_pct": 100.0 * f}
    elif case == "black_offset":
        d = rng_case.uniform(0.5, 2.0)
        kw["offset_add"] = d
        effect = {"offset_raise_cd_m2": d}
    elif case == "warmup":
        d, tau = rng_case.uniform(0.05, 0.15), rng_case.uniform(180.0, 600.0)
        kw["warm"] = 1.0 - d * np.exp(-(chk[:, 0] - chk[0, 0]) / tau)
        effect = {"warmup_deficit_pct_at_start": 100.0 * d, "warmup_tau_s": tau}
    elif case == "uniformity":
        extra = rng_case.uniform(0.04, 0.10)
        kw["falloff_k"] = disp["falloff_k"] + extra / r2_physical(0.6, 0.6)
        effect = {"extra_corner_drop_pct": 100.0 * extra,
                  "falloff_k_check": kw["falloff_k"]}
    lum_cal = luminance(disp, cal[:, 3], cal[:, 1], cal[:, 2],
                        wander=wander[:n], offset_wander=off_w[:n])
    lum_chk = luminance(disp, chk[:, 3], chk[:, 1], chk[:, 2],
                        wander=wander[n:], offset_wander=off_w[n:], **kw)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "calib.csv", f"blind-{case}-{seed}-calib", device, cal,
              meter(rng_case, lum_cal, floor))
    write_csv(out / "check.csv", f"blind-{case}-{seed}-check", device, chk,
              meter(rng_case, lum_chk, floor))
    truth = {
        "generator": "bench/blind/display_gen.py", "case": case, "seed": seed,
        "expected": EXPECTED[case], "effect": effect, "display": disp,
        "meter": {"device": device, "floor_cd_m2": floor, "noise_rel": NOISE_REL,
                  "noise_abs_cd_m2": NOISE_ABS_CD_M2, "digits": 4},
        "runs": {"n_levels": len(levels), "positions_norm": positions(), "repeats": 2,
                 "seconds_per_reading": SECONDS_PER_READING, "gap_between_runs_s": gap_s,
                 "mean_gain_wander_pct_calib": 100.0 * float(np.mean(wander[:n])),
                 "mean_gain_wander_pct_check": 100.0 * float(np.mean(wander[n:]))},
        "fit_command": "python -m calibration fit calib.csv --out CAL --dac-bits none",
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=2) + "\n")
    return truth


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", required=True, choices=CASES)
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--out", required=True, help="folder written: calib.csv, check.csv, truth.json")
    args = ap.parse_args(argv)
    truth = generate(args.case, args.seed, args.out)
    print(json.dumps({"case": truth["case"], "seed": truth["seed"],
                      "expected": truth["expected"], "effect": truth["effect"]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
