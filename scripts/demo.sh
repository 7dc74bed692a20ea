#!/usr/bin/env bash
# The main job on embedded defaults: design -> calibration -> gloss fit -> stimuli -> sessions ->
# analysis report -> sim-to-real report. Called by `make demo` (which sets PY, OUT, HOME).
# Each run writes into a new folder out/demo-<UTC time>; nothing from an earlier run is touched.
set -euo pipefail
PY=${PY:-.venv/bin/python}
OUT=${OUT:-out}
RUN="$OUT/demo-$(date -u +%Y%m%dT%H%M%SZ)"
mkdir -p "$RUN"
RUN=$(cd "$RUN" && pwd)  # absolute: the session app refuses a relative --data
ln -sfn "$(basename "$RUN")" "$OUT/latest"
# Each xvfb-run keeps its X authority file here (-f), so it makes and removes no temporary
# folder of its own (that removal once failed in CI after the command had passed).
XAUTH="$RUN/Xauthority"
t0=$(date +%s)
STEP_NAME=""; STEP_T=$t0; STEP_TIMES=()
# Each step's heading with the time since the start; at the end, each step's own time and the
# pipeline's (issue 38: the demo says how long it took).
step() {
  local now; now=$(date +%s)
  [ -n "$STEP_NAME" ] && STEP_TIMES+=("$(printf '%5d s  %s' $(( now - STEP_T )) "${STEP_NAME%%:*}")")
  STEP_NAME=$*; STEP_T=$now
  echo; echo "== $* ($(( now - t0 )) s)"
}

# --- design ---
step "study design"
"$PY" -m studydesign check
"$PY" -m studydesign show
mkdir -p "$RUN/design"
"$PY" -m studydesign stimuli --out "$RUN/design/stimuli.csv"
"$PY" -m studydesign json > "$RUN/design/design.json"
# --- end design ---

# --- calibration ---
step "display calibration: simulated PR-655 on a pseudo-terminal, PsychoPy window under Xvfb"
# The fake photometer and the procedure share one X display: the fake reads the window's pixels.
# That display has the design's resolution (as the lab's CRT would), not the sessions' 1280x1024.
# Fewer levels and repeats and a short settling time than a lab run, to keep the demo near a minute;
# 2 repeats, the fewest from which the sim-to-real step can estimate the photometer's noise.
CAL="$RUN/calibration"
mkdir -p "$CAL"
CAL_RES=$("$PY" -c 'from studydesign import load_design; w, h = load_design().display.resolution_px; print(f"{w}x{h}")')
# Xvfb has no vertical blank (frames come at hundreds of Hz): record the design's nominal rate,
# flagged in the calibration record as given, not measured. A lab run measures it.
CAL_HZ=$("$PY" -c 'from studydesign import load_design; print(load_design().display.nominal_refresh_hz)')
xvfb-run -a -f "$XAUTH" -s "-screen 0 ${CAL_RES}x24" bash -c '
  set -euo pipefail
  PY=$1; CAL=$2; HZ=$3; CHECK=$4
  "$PY" -m calibration fake-photometer --device pr655 --aim "$CAL/aim.json" \
    --port-file "$CAL/port" --seed 1 >"$CAL/fake-photometer.log" 2>&1 &
  fake=$!
  trap "kill $fake 2>/dev/null || true" EXIT
  for _ in $(seq 150); do [ -s "$CAL/port" ] && break; sleep 0.1; done
  [ -s "$CAL/port" ] || { echo "fake photometer did not start:"; cat "$CAL/fake-photometer.log"; exit 1; }
  "$PY" -m calibration run --device pr655 --port "$(cat "$CAL/port")" --out "$CAL" \
    --sim-aim "$CAL/aim.json" --fast --levels 9 --repeats 2 --uniformity-levels 3 \
    --validation 5 --calibration-id demo --refresh-hz "$HZ"
  # A separate check run against the calibration (no refit): warm-up drift (white every 0.2 s
  # until two 1-s windows agree within 0.5 %; a lab check reads every 10 s over 2-min windows),
  # then 5 levels at the centre and 3 at the other 8 positions. Exit code 1 means some patch is
  # outside tolerance: reported in check.json, not a failure of the demo.
  rc=0
  "$PY" -m calibration check --calibration "$CAL/calibration.json" --device pr655 \
    --port "$(cat "$CAL/port")" --out "$CHECK" --sim-aim "$CAL/aim.json" --fast \
    --warmup-interval-s 0.2 --warmup-window-s 1 --warmup-max-s 20 || rc=$?
  [ "$rc" -le 1 ]
' calibration "$PY" "$CAL" "$CAL_HZ" "$RUN/calibration-check"
# --- end calibration ---

# --- gloss fit ---
step "gloss fit: synthetic HDR photos of the gloss spheres -> Ward parameters (basis method)"
# The lab's photos are not in the repository: render 6 of the 11 levels (clear-coat spheres with
# noise, glare, vignetting and misregistration), then fit them as the lab's photos would be.
# The gloss table spans 0-100 %, so it covers the rendered levels (10-90 %).
"$PY" -m stimuli synth-photos "$RUN/glossfit/photos" --levels 0,20,40,60,80,100 --seed 1
"$PY" -m stimuli fit-gloss "$RUN/glossfit/photos" --out "$RUN/glossfit"
# A photometric-stereo-like set too: a clear-coated sphere under 12 directional lights (16-bit
# PNGs, DiLiGenT's layout), Ward fitted on lights 1-11; light 12 is held out below.
"$PY" -m stimuli synth-lights "$RUN/glossfit-lights/photos" --size 48 --lights 12 --seed 1
"$PY" -m stimuli fit-gloss "$RUN/glossfit-lights/photos" --lights 1-11 --out "$RUN/glossfit-lights"
# --- end gloss fit ---

# --- stimuli ---
step "stimuli: Mitsuba (LLVM) renders of the ellipsoid arrays with the Ward BSDF, tone-mapped, gamma-corrected"
# The gloss table and calibration of the steps above when they exist, else the documented defaults.
mkdir -p "$RUN/stimuli"
STIM_OPTS=()
[ -f "$RUN/glossfit/gloss_table.csv" ] && STIM_OPTS+=(--gloss-table "$RUN/glossfit/gloss_table.csv")
[ -f "$RUN/calibration/calibration.json" ] && STIM_OPTS+=(--calibration "$RUN/calibration/calibration.json")
"$PY" -m stimuli check-env
"$PY" -m stimuli render --set preview --out "$RUN/stimuli/preview" --size 128 --spp 16 \
  --workers 0 --no-progress ${STIM_OPTS[@]+"${STIM_OPTS[@]}"} >"$RUN/stimuli/preview-summary.json"
"$PY" -m stimuli contact-sheet "$RUN/stimuli/preview" "$RUN/stimuli/preview/contact_sheet.png"
# All 162 experiment stimuli, small and few samples so the demo stays near a minute or two
# (a lab run: --size at the native width and no --spp, i.e. the design's spp per gloss level; see
# bench/stimuli_throughput.py). One worker: its Dr.Jit threads use all cores.
"$PY" -m stimuli render --set experiment --out "$RUN/stimuli/experiment" --size 96 --spp 8 \
  --workers 1 --no-progress ${STIM_OPTS[@]+"${STIM_OPTS[@]}"} >"$RUN/stimuli/experiment-summary.json"
"$PY" -m stimuli verify "$RUN/stimuli/experiment"
"$PY" -m stimuli export-print --depth-level 5 --spacing-cm 0.05 "$RUN/stimuli/print_depth05.stl"
# --- end stimuli ---

# --- experiment ---
step "experiment: two simulated humanlike observers x two sessions through the app (Xvfb, XTEST input)"
# The real session app, windowed under Xvfb, a simulated participant at the X mouse and keyboard;
# --fast: no waiting for the vertical blank or the observer's response times.
STIM_MANIFEST="$RUN/stimuli/experiment/manifest.csv"
[ -f "$STIM_MANIFEST" ] || { echo "error: the stimuli step wrote no $STIM_MANIFEST" >&2; exit 1; }
EXP_CAL="$RUN/calibration/calibration.json"
EXP_FLAGS=()
# The stimuli should be gamma-corrected for this calibration; if the stimuli step used another
# one, say so and run anyway (a lab session would refuse; the flag is recorded in the log).
if ! "$PY" - "$STIM_MANIFEST" "$EXP_CAL" <<'PYEOF'
import sys
import pandas as pd
from calibration import load_calibration
ids = set(pd.read_csv(sys.argv[1], dtype=str)["calibration_id"])
sys.exit(0 if ids == {load_calibration(sys.argv[2]).calibration_id} else 1)
PYEOF
then
  echo "note: stimuli were corrected for another calibration; running with --accept-calibration-mismatch"
  EXP_FLAGS+=(--accept-calibration-mismatch)
fi
xvfb-run -a -f "$XAUTH" -s "-screen 0 1280x1024x24" bash -c '
  set -euo pipefail
  PY=$1; MANIFEST=$2; CAL=$3; DATA=$4; shift 4
  for p in D01 D02; do
    for s in 1 2; do
      "$PY" -m experiment run --participant "$p" --session "$s" --stimuli "$MANIFEST" \
        --calibration "$CAL" --data "$DATA" --simulate humanlike --fast "$@"
    done
  done
' experiment "$PY" "$STIM_MANIFEST" "$EXP_CAL" "$RUN/data" ${EXP_FLAGS[@]+"${EXP_FLAGS[@]}"}
# Ideal observers (same ids, so the same plans) for the sim-to-real diagnosis, without the app.
"$PY" -m experiment simulate --observer ideal --participants D01 D02 --data "$RUN/data_ideal" --seed 1
# --- end experiment ---

# --- power ---
step "power: how many participants for the seed's gloss x depth interaction, from a pilot"
# A pilot of four simulated humanlike observers (no app; the gap step below fits the observers to
# it too), the gloss model fitted to it, planned studies of 4, 6, ..., 24 new participants drawn
# from its random effects, 1,000 simulated studies per N, refitted and tested (Type II Wald).
"$PY" -m experiment simulate --observer humanlike --participants PILOT1 PILOT2 PILOT3 PILOT4 \
  --data "$RUN/pilot" --seed 2
"$PY" -m analysis power "$RUN/pilot" --out "$RUN/power" --model gloss --term gloss:depth \
  --participants 4:24:2 --n-sim 1000 --seed 1 --workers 2 --quiet
# The pilot's interaction is large (every N reaches 80 %); the same at a quarter of its size,
# 200 studies per N (to keep the step short), with the smallest effect 12 participants detect.
"$PY" -m analysis power "$RUN/pilot" --out "$RUN/power-quarter" --model gloss --term gloss:depth \
  --participants 4:24:2 --n-sim 200 --seed 1 --workers 2 --quiet --scale gloss:depth=0.25 \
  --detect 12
# --- end power ---

# --- analysis report ---
step "analysis report: figures, mixed models (lme4's formulation), bootstrap, power"
# 2,000 bootstrap runs per model instead of the default 10,000, to keep the demo near a minute.
POWER_OPT=()
[ -f "$RUN/power-quarter/power.json" ] && POWER_OPT=(--power "$RUN/power" "$RUN/power-quarter")
"$PY" -m analysis report "$RUN/data" --out "$RUN/report" --bootstrap 2000 --seed 1 \
  ${POWER_OPT[@]+"${POWER_OPT[@]}"}
# --- end analysis report ---

# --- image statistics ---
step "image statistics: a stratified subset of the imagestats set, statistics on Dask, relation to gloss"
# 2 light fields (the experiment's indoor and outdoor captures) x 1 array x gloss levels 2,6,10 x
# depth levels 2,6,10 = 18
# images at 192 px (the smallest size whose array square suits the Portilla-Simoncelli pyramid),
# 16 spp; the full set is 58,564 images (protocol.md, 7.1).
IS="$RUN/imagestats"
"$PY" -m stimuli render --set imagestats --filter light_field=aerodynamics_workshop,immenstadter_horn \
  --filter array_index=0 --filter gloss_level=2,6,10 --filter depth_level=2,6,10 \
  --size 192 --spp 16 --workers 1 --out "$IS/renders" --no-progress
"$PY" -m analysis imagestats "$IS/renders" --out "$IS/stats.parquet" --workers 2 \
  --batch-size 3 --quiet
"$PY" -m analysis imagestats relate "$IS/stats.parquet" --sessions "$RUN/data" \
  --out "$IS/report" --n-boot 200 --seed 1
# --- end image statistics ---

# --- sim-to-real gap ---
step "sim-to-real gap: observer, display and render layers, then which layer carries the gap"
GAP="$RUN/gap"
mkdir -p "$GAP"
GAP_REAL=(); GAP_SIM=()
# Observer, as a lab would: a pilot of four (simulated humanlike observers, no app), the
# humanlike observer fitted to it (experiment fit-observer), then the app's humanlike sessions
# (other participants) diagnosed against the fitted observer (expected: not a gap -- no gap that
# matters, or inconclusive with the misfit these data detect and how many more participants
# decide) and
# against the ideal observer (expected: central tendency + crosstalk, the humanlike observer's
# known effects), each with three bootstrap seeds: the verdicts must not depend on --seed.
if [ -d "$RUN/data/sessions" ] && [ -d "$RUN/data_ideal/sessions" ]; then
  # (made by the power step above; made here when that step was left out)
  [ -d "$RUN/pilot/sessions" ] || "$PY" -m experiment simulate --observer humanlike \
    --participants PILOT1 PILOT2 PILOT3 PILOT4 --data "$RUN/pilot" --seed 2
  OBS_SIM="$RUN/data_ideal/sessions"; SIMS=("ideal=$OBS_SIM")
  if "$PY" -m experiment fit-observer "$RUN/pilot" --out "$GAP/observers.toml"; then
    OBS_SIM="$GAP/observers.toml"; SIMS=("fitted=$OBS_SIM" "${SIMS[@]}")
  else
    echo "gap observer layer: fit-observer failed; diagnosing against the ideal observer only"
  fi
  for pair in "${SIMS[@]}"; do
    for seed in 0 1 2; do
      "$PY" -m analysis gap diagnose --layer observer --real "$RUN/data/sessions" \
        --sim "${pair#*=}" --out "$GAP/observer_${pair%%=*}_seed$seed" --seed "$seed" \
        2>>"$GAP/observer_warnings.txt" | tee -a "$GAP/observer_verdicts.txt"
    done
  done
  GAP_REAL+=("observer=$RUN/data/sessions"); GAP_SIM+=("observer=$OBS_SIM")
else
  echo "error: the gap observer layer needs \$RUN/data/sessions (humanlike, app) and \$RUN/data_ideal/sessions (ideal observer)" >&2; exit 1
fi
# Display: a separate check run (measured after the calibration, never the readings the
# calibration was fitted from) against the calibration.
CHECK="$RUN/calibration-check"
if [ -f "$RUN/calibration/calibration.json" ] && [ -f "$CHECK/readings.csv" ]; then
  "$PY" -m analysis gap diagnose --layer display --real "$CHECK" \
    --sim "$RUN/calibration" --out "$GAP/display"
  GAP_REAL+=("display=$CHECK"); GAP_SIM+=("display=$RUN/calibration")
else
  echo "error: the gap display layer needs \$RUN/calibration/calibration.json and the check run's \$RUN/calibration-check/readings.csv" >&2; exit 1
fi
# Render: the synthetic photos against their Ward fit (the gloss fit's residual files).
if compgen -G "$RUN/glossfit/residuals/*.npz" >/dev/null; then
  "$PY" -m analysis gap diagnose --layer render --real "$RUN/glossfit" --sim "$RUN/glossfit" \
    --out "$GAP/render"
  GAP_REAL+=("render=$RUN/glossfit")
else
  echo "error: the gap render layer needs \$RUN/glossfit/residuals/*.npz (the gloss fit wrote none)" >&2; exit 1
fi
# Render, held out: the directional set's light 12, which the fit never saw.
"$PY" -m analysis gap diagnose --layer render --real "$RUN/glossfit-lights/photos" --lights 12 \
  --sim "$RUN/glossfit-lights" --out "$GAP/render-heldout-light"
if [ ${#GAP_REAL[@]} -ge 2 ]; then
  "$PY" -m analysis gap diagnose --layer all --real "$(IFS=,; echo "${GAP_REAL[*]}")" \
    --sim "$(IFS=,; echo "${GAP_SIM[*]}")" --out "$GAP/all"
fi
# Each verdict is one of three outcomes (gap / no gap that matters / inconclusive): one line per
# report, the outcome first, so the demo shows them at a glance.
for f in "$GAP"/*/diagnosis.json "$GAP"/all/*/diagnosis.json; do
  [ -f "$f" ] || continue
  "$PY" - "$f" <<'PYEOF'
import json, sys
d = json.load(open(sys.argv[1]))
v = d["verdict"]
outcome = v if v in ("no_gap_that_matters", "inconclusive") else "GAP"
more = ""
if v == "inconclusive" and d.get("detectable"):
    det, dec = d["detectable"], d["to_decide"]
    val = "n/a" if det["value"] is None else f"{det['value']:.2g}"
    more = f" (detectable {val} {det['unit'][:20]}; to decide: {dec['words']})"
print(f"gap outcome: {outcome:20s} {d['layer']:9s} {v}{more}  <- {sys.argv[1]}")
PYEOF
done
echo "blind benchmarks (not run here; the render layer renders with Mitsuba and takes longest): $PY -m analysis gapbench --layer all --trials 40 --seed 1 --threshold-reps 5; harder, seeds pooled: $PY -m analysis gapbench --layer observer --harder --trials 30 --seed 1 2 3"
# --- end sim-to-real gap ---

step "done"
echo "step times:"; printf '  %s\n' "${STEP_TIMES[@]}"
total=$(( $(date +%s) - t0 ))
echo "demo pipeline time: ${total} s ($(( total / 60 )) min $(( total % 60 )) s)"
echo "demo output: $RUN"
if [ -f "$RUN/report/index.html" ]; then echo "report: $RUN/report/index.html"; fi
