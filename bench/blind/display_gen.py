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

NEW_CASES = ("gamma_tilt", "apl_loading", "offset_warmup")
CASES = ("clean", "repeat_pass", "gain", "black_offset", "warmup", "uniformity", *NEW_CASES)
RUNS = ("full", "short")
TOLERANCE_PCT = 1.0  # design.toml [gap] display_tolerance_pct
STRENGTH_UNIT = {"gamma_tilt": "gamma added at the top row (y = +0.6), taken at the bottom",
                 "apl_loading": "fraction of the light above black lost by a full-field white",
                 "offset_warmup": "scale of offset_cd_m2 and warm_deficit"}
#: What the diagnosis should say for each case: "none" (no gap) or the effect's name.
#: Catalogue names as the diagnosis's output (diagnosis.json "ranking") lists them.
EXPECTED = {"clean": "none", "repeat_pass": "none", "gain": "gain_change",
            "black_offset": "black_offset", "warmup": "warmup_drift",
            "uniformity": "nonuniformity", "gamma_tilt": "unexplained",
            "apl_loading": "unexplained", "offset_warmup": "black_offset + warmup_drift"}

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


def schedule(rng, levels, t0_s, n_repeats=2, *, where=None):
    """Rows (time_s, x, y, level, repeat) of one run in the order measured (at ``where``'s
    positions, default the 3 x 3 grid)."""
    rows, t = [], t0_s
    for x, y in (positions() if where is None else where):
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
              falloff_k=None, warm=None, gamma_add=0.0, apl_loss=0.0):
    """True luminance of each reading, cd/m^2.

    ``gamma_add``: added to the gamma (per reading: a gamma that varies across the screen);
    ``apl_loss``: a full-field patch of relative luminance a = v^gamma loses a fraction
    apl_loss * a of its light above black (the display's power limit, ABL)."""
    k = disp["falloff_k"] if falloff_k is None else falloff_k
    s = 1.0 - k * r2_physical(x, y)
    g = disp["gain_cd_m2"] * gain_factor * (1.0 + wander) * s
    if warm is not None:
        g = g * warm
    off = disp["offset_cd_m2"] * (1.0 + offset_wander) + offset_add
    rel = np.power(v, disp["gamma"] + gamma_add)
    return off + g * rel * (1.0 - apl_loss * np.power(v, disp["gamma"]))


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


def check_grid(run):
    """Levels and positions of the check run: ``full`` as the calibration; ``short`` 9 levels
    at the centre and the four corners (a quick check before a session)."""
    if run == "full":
        return np.linspace(0.0, 1.0, 17), positions()
    corners = [(x, y) for x, y in positions() if x != 0.0 and y != 0.0]
    return np.linspace(0.0, 1.0, 9), [(0.0, 0.0), *corners]


def size_pct(lum, ref, white_cd_m2):
    """RMS over the readings above 5 % of white of (lum - ref) / ref, in % (design.toml [gap]
    display_tolerance_pct's measure), from the true luminance (no meter noise)."""
    keep = ref > 0.05 * white_cd_m2
    return float(100.0 * np.sqrt(np.mean(((lum[keep] - ref[keep]) / ref[keep]) ** 2)))


def size_worst_pct(lum, ref, white_cd_m2, chk):
    """The largest ``size_pct`` over the readings of one screen position or of one drive level
    (the worst subset), in %."""
    keep = ref > 0.05 * white_cd_m2
    subsets = [(chk[:, 1] == x) & (chk[:, 2] == y) for x, y in {(r[1], r[2]) for r in chk}]
    subsets += [chk[:, 3] == v for v in np.unique(chk[:, 3])]
    return max(size_pct(lum[m & keep], ref[m & keep], 0.0) for m in subsets if np.any(m & keep))


def new_effect(case, strength, disp, chk, shape):
    """Keyword arguments of ``luminance`` for a new case at ``strength`` (see the module
    docstring); ``shape`` holds the case's fixed draws."""
    if case == "gamma_tilt":
        return {"gamma_add": strength * chk[:, 2] / 0.6}
    if case == "apl_loading":
        return {"apl_loss": strength}
    # offset_warmup: both at once, in the fixed ratio drawn for the seed.
    t = chk[:, 0] - chk[0, 0]
    return {"offset_add": strength * shape["offset_cd_m2"],
            "warm": 1.0 - strength * shape["warm_deficit"] * np.exp(-t / shape["warm_tau_s"])}


def scale_new(case, target_pct, disp, chk, base_kw, white, rng_eff):
    """(strength, shape, kwargs) at which the new effect's size is ``target_pct``."""
    shape = {}
    ref = luminance(disp, chk[:, 3], chk[:, 1], chk[:, 2], **base_kw)
    if case == "offset_warmup":
        # The run's first third darker: a warm-up whose deficit decays with tau = a ninth of
        # the run (e^-3 = 5 % left at a third); offset and warm-up each given half the size.
        shape["warm_tau_s"] = float((chk[-1, 0] - chk[0, 0]) / 9.0)
        shape["offset_cd_m2"], shape["warm_deficit"] = 1.0, 0.0
        one = size_pct(luminance(disp, chk[:, 3], chk[:, 1], chk[:, 2], **base_kw,
                                 **new_effect(case, 1.0, disp, chk, shape)), ref, white)
        shape.update(offset_cd_m2=0.0, warm_deficit=1.0)
        other = size_pct(luminance(disp, chk[:, 3], chk[:, 1], chk[:, 2], **base_kw,
                                   **new_effect(case, 1.0, disp, chk, shape)), ref, white)
        shape.update(offset_cd_m2=float(rng_eff.uniform(0.8, 1.2)) / one, warm_deficit=1.0 / other)

    def size(strength):
        kw = {**base_kw, **new_effect(case, strength, disp, chk, shape)}
        return size_pct(luminance(disp, chk[:, 3], chk[:, 1], chk[:, 2], **kw), ref, white)

    lo, hi = 0.0, 0.01
    while size(hi) < target_pct:
        hi *= 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if size(mid) < target_pct else (lo, mid)
    strength = 0.5 * (lo + hi)
    return strength, shape, new_effect(case, strength, disp, chk, shape)


def old_effect(case, rng_case, chk):
    """(luminance kwargs, truth) of the cases of issue 38, drawn as they were."""
    if case == "gain":
        f = rng_case.uniform(0.10, 0.30) * rng_case.choice([-1.0, 1.0])
        return {"gain_factor": 1.0 + f}, {"gain_change_pct": 100.0 * f}
    if case == "black_offset":
        d = rng_case.uniform(0.5, 2.0)
        return {"offset_add": d}, {"offset_raise_cd_m2": d}
    if case == "warmup":
        d, tau = rng_case.uniform(0.05, 0.15), rng_case.uniform(180.0, 600.0)
        return ({"warm": 1.0 - d * np.exp(-(chk[:, 0] - chk[0, 0]) / tau)},
                {"warmup_deficit_pct_at_start": 100.0 * d, "warmup_tau_s": tau})
    return {}, {}


def generate(case, seed, out, *, run="full", multiple=1.0):
    """Write ``out``/calib.csv, check.csv and truth.json for one case and seed.

    ``run``: the check run's size (``full`` or ``short``); ``multiple``: the new cases' size in
    tolerances (1 % of luminance, RMS over the readings above 5 % of white)."""
    if case not in CASES:
        raise ValueError(f"--case {case!r}: choose one of {', '.join(CASES)}")
    if run not in RUNS:
        raise ValueError(f"--run {run!r}: choose one of {', '.join(RUNS)}")
    new = case in NEW_CASES
    # One stream per (case, seed): the same seed gives the same display in every case. The
    # new cases take `clean`'s stream (their no-effect data) and draw their effect apart.
    rng = np.random.default_rng([seed, 7919])
    disp = draw_display(rng)
    rng_case = np.random.default_rng([seed, 0 if new else CASES.index(case), 104729])
    rng_eff = np.random.default_rng([seed, CASES.index(case), 104729, 7])
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
    chk_levels, chk_pos = check_grid(run) if case != "repeat_pass" else (levels, positions())
    if case == "repeat_pass" and run == "short":
        chk_levels, chk_pos = levels, chk_pos[:1] + chk_pos[-4:]
    cal = schedule(rng_case, levels, 0.0)
    chk = schedule(rng_case, chk_levels, cal[-1, 0] + SECONDS_PER_READING + gap_s, where=chk_pos)
    times = np.concatenate([cal[:, 0], chk[:, 0]])
    wander = ou_path(rng_case, times, disp["wander_sd"], WANDER_TAU_S)
    off_w = ou_path(rng_case, times, disp["offset_wander_sd"], WANDER_TAU_S)
    n = len(cal)
    base_kw = {"wander": wander[n:], "offset_wander": off_w[n:]}
    white = disp["offset_cd_m2"] + disp["gain_cd_m2"]
    if new:
        strength, shape, kw = scale_new(case, multiple * TOLERANCE_PCT, disp, chk, base_kw,
                                        white, rng_eff)
        effect = {"strength": strength, "unit": STRENGTH_UNIT[case], **shape}
    elif case == "uniformity":
        extra = rng_case.uniform(0.04, 0.10)
        kw = {"falloff_k": disp["falloff_k"] + extra / r2_physical(0.6, 0.6)}
        effect = {"extra_corner_drop_pct": 100.0 * extra, "falloff_k_check": kw["falloff_k"]}
    else:
        kw, effect = old_effect(case, rng_case, chk)
    lum_cal = luminance(disp, cal[:, 3], cal[:, 1], cal[:, 2],
                        wander=wander[:n], offset_wander=off_w[:n])
    lum_ref = luminance(disp, chk[:, 3], chk[:, 1], chk[:, 2], **base_kw)
    lum_chk = luminance(disp, chk[:, 3], chk[:, 1], chk[:, 2], **base_kw, **kw)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "calib.csv", f"blind-{case}-{seed}-calib", device, cal,
              meter(rng_case, lum_cal, floor))
    write_csv(out / "check.csv", f"blind-{case}-{seed}-check", device, chk,
              meter(rng_case, lum_chk, floor))
    size = size_pct(lum_chk, lum_ref, white)
    worst = size_worst_pct(lum_chk, lum_ref, white, chk)
    truth = {
        "generator": "bench/blind/display_gen.py", "case": case, "seed": seed,
        "expected": EXPECTED[case], "in_catalogue": not new or case == "offset_warmup",
        "run": run, "multiple_asked": multiple if new else None,
        "size": size, "size_unit": "% of luminance, RMS over check readings above 5 % of white",
        "tolerance": TOLERANCE_PCT, "size_in_tolerances": size / TOLERANCE_PCT,
        "size_worst_pct": worst, "size_worst_unit": "the same, at the worst position or level",
        "effect": effect, "display": disp,
        "meter": {"device": device, "floor_cd_m2": floor, "noise_rel": NOISE_REL,
                  "noise_abs_cd_m2": NOISE_ABS_CD_M2, "digits": 4},
        "runs": {"n_levels": len(levels), "positions_norm": positions(), "repeats": 2,
                 "check_levels": len(chk_levels), "check_positions_norm": chk_pos,
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
    ap.add_argument("--run", choices=RUNS, default="full",
                    help="the check run: full (as the calibration, default) or short")
    ap.add_argument("--multiple", type=float, default=1.0,
                    help="new cases: effect size in tolerances (1 %% of luminance); default 1")
    args = ap.parse_args(argv)
    truth = generate(args.case, args.seed, args.out, run=args.run, multiple=args.multiple)
    print(json.dumps({k: truth[k] for k in ("case", "seed", "expected", "run", "size",
                                            "size_in_tolerances", "effect")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
