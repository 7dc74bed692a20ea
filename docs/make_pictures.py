"""Make the documentation's pictures by running small versions of the pipeline's steps.

Run by ``make docs`` (and so by ``make test``) before Sphinx: every picture on the site is made
by the code it shows, never by hand. Each step is the command a guide shows, with the smallest
settings that still draw a real picture (tiny renders, few levels, no bootstrap), so the whole
script stays near a minute on 2 cores. The pictures go into ``docs/_generated/`` (git-ignored),
the step outputs into ``docs/_generated/run/``; a second run redoes everything (nothing cached,
so a picture cannot go stale).

Usage: ``python docs/make_pictures.py [--out docs/_generated]``; needs Xvfb (``xvfb-run``) and
Debian's ``chromium`` for the HTML reports' screenshots, as ``make test`` does.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


def xvfb(run_dir: Path, screen: str = "1280x1024x24") -> list[str]:
    """``xvfb-run`` with its X authority file in ``run_dir``: xvfb-run then makes no temporary
    folder of its own, whose removal at exit once failed in CI (exit 5, "problem while cleaning
    up temporary directory") after the session had run and saved its trials."""
    return ["xvfb-run", "-a", "-f", str(run_dir / "Xauthority"), "-s", f"-screen 0 {screen}"]


CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


def run(cmd: list[str], *, log: Path, stdout: Path | None = None, ok=(0,)) -> None:
    """Run one pipeline command from the project root; on failure print its output and raise."""
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    with open(log, "a") as err, open(stdout or os.devnull, "w") as captured:
        err.write("$ " + " ".join(cmd) + "\n")
        err.flush()
        proc = subprocess.run(cmd, cwd=ROOT, env=env, stdout=captured if stdout else err,
                              stderr=err, check=False)
    if proc.returncode not in ok:
        sys.stderr.write(log.read_text()[-4000:])
        raise RuntimeError(f"make_pictures: `{' '.join(cmd)}` exited {proc.returncode} "
                           f"(its output is above and in {log})")


def screenshot(page: Path, png: Path, *, width: int = 1280, height: int = 1600) -> None:
    """A headless-Chromium screenshot of an HTML page (fresh profile, no GPU, no network)."""
    with tempfile.TemporaryDirectory(prefix="chromium-profile-") as profile:
        cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
               "--disable-background-networking", "--no-first-run", "--disable-component-update",
               f"--user-data-dir={profile}", f"--window-size={width},{height}",
               f"--screenshot={png}", page.resolve().as_uri()]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    if proc.returncode != 0 or not png.is_file():
        raise RuntimeError(f"chromium could not screenshot {page}: {proc.stderr[-2000:]}")


def calibration(run_dir: Path, pics: Path, log: Path) -> None:
    """A simulated PR-655 on a pseudo-terminal measures a PsychoPy window under Xvfb (as the
    demo does, fewer levels), then a check run against it: the display layer's real data."""
    from studydesign import load_design

    design = load_design()
    w, h = design.display.resolution_px
    cal, check = run_dir / "calibration", run_dir / "calibration-check"
    cal.mkdir(parents=True)
    script = (
        'set -euo pipefail; PY=$1; CAL=$2; CHECK=$3; HZ=$4\n'
        '"$PY" -m calibration fake-photometer --device pr655 --aim "$CAL/aim.json" '
        '--port-file "$CAL/port" --seed 1 >"$CAL/fake-photometer.log" 2>&1 &\n'
        'fake=$!; trap "kill $fake 2>/dev/null || true" EXIT\n'
        'for _ in $(seq 150); do [ -s "$CAL/port" ] && break; sleep 0.1; done\n'
        '"$PY" -m calibration run --device pr655 --port "$(cat "$CAL/port")" --out "$CAL" '
        '--sim-aim "$CAL/aim.json" --fast --levels 6 --repeats 2 --uniformity-levels 2 '
        '--validation 3 --calibration-id docs --refresh-hz "$HZ"\n'
        'rc=0; "$PY" -m calibration check --calibration "$CAL/calibration.json" --device pr655 '
        '--port "$(cat "$CAL/port")" --out "$CHECK" --sim-aim "$CAL/aim.json" --fast '
        '--grid 1 --warmup-interval-s 0.2 --warmup-window-s 1 --warmup-max-s 5 || rc=$?; [ "$rc" -le 1 ]\n')
    run([*xvfb(run_dir, f"{w}x{h}x24"), "bash", "-c", script, "calibration",
         PY, str(cal), str(check), str(design.display.nominal_refresh_hz)], log=log)
    for name in ("gamma.png", "uniformity.png"):
        shutil.copy(cal / name, pics / f"calibration_{name}")


def stimuli(run_dir: Path, pics: Path, log: Path) -> None:
    """The experiment set at thumbnail size (the session needs all of it) and its contact sheet."""
    stim = run_dir / "stimuli"
    run([PY, "-m", "stimuli", "render", "--set", "experiment", "--out", str(stim),
         "--size", "48", "--spp", "8", "--workers", "0", "--no-progress",
         "--calibration", str(run_dir / "calibration" / "calibration.json")],
        log=log, stdout=run_dir / "stimuli-summary.json")
    run([PY, "-m", "stimuli", "contact-sheet", str(stim), str(pics / "contact_sheet.png")],
        log=log)


def session(run_dir: Path, pics: Path, log: Path) -> None:
    """The session app under Xvfb with a simulated observer at the X mouse: it saves the first
    answered trial's screen, is stopped (Esc twice) at trial 3, is resumed by the same command
    and stopped again at trial 5; ``status`` after each stop (the texts the session guide shows)."""
    cmd = [*xvfb(run_dir), PY, "-m", "experiment", "run", "--participant", "D01", "--session", "1",
           "--stimuli", str(run_dir / "stimuli" / "manifest.csv"),
           "--calibration", str(run_dir / "calibration" / "calibration.json"),
           "--data", str(run_dir / "data"), "--simulate", "humanlike", "--fast"]
    status = [PY, "-m", "experiment", "status", "--participant", "D01",
              "--data", str(run_dir / "data")]
    # Exit 3: the session was paused, its trials kept (what the guide's resume section shows).
    run([*cmd, "--screenshot", str(pics / "session_screen.png"), "--simulate-quit-at", "3"],
        log=log, ok=(3,), stdout=pics / "session_stopped.txt")
    run(status, log=log, stdout=pics / "session_status_stopped.txt")
    run([*cmd, "--simulate-quit-at", "5"], log=log, ok=(3,), stdout=pics / "session_resumed.txt")
    run(status, log=log, stdout=pics / "session_status_resumed.txt")


def analysis(run_dir: Path, pics: Path, log: Path) -> None:
    """Simulated sessions (observer model, no app), the analysis report without bootstrap."""
    for kind, folder in (("humanlike", "sim_human"), ("ideal", "sim_ideal")):
        run([PY, "-m", "experiment", "simulate", "--observer", kind, "--participants", "S01",
             "S02", "S03", "--data", str(run_dir / folder), "--seed", "1"], log=log)
    report = run_dir / "report"
    run([PY, "-m", "analysis", "report", str(run_dir / "sim_human"), "--out", str(report),
         "--bootstrap", "0", "--quiet"], log=log)
    for png in sorted(report.glob("*.png")):
        shutil.copy(png, pics / f"analysis_{png.name}")
    screenshot(report / "index.html", pics / "analysis_report.png")


def gap(run_dir: Path, pics: Path, log: Path) -> None:
    """The gap report of the observer and display layers (render: see ``render_gap``)."""
    gapdir = run_dir / "gap"
    run([PY, "-m", "analysis", "gap", "diagnose", "--layer", "observer",
         "--real", str(run_dir / "sim_human" / "sessions"),
         "--sim", str(run_dir / "sim_ideal" / "sessions"), "--out", str(gapdir / "observer")],
        log=log, stdout=pics / "gap_observer.txt")
    run([PY, "-m", "analysis", "gap", "diagnose", "--layer", "display",
         "--real", str(run_dir / "calibration-check"), "--sim", str(run_dir / "calibration"),
         "--out", str(gapdir / "display")], log=log, stdout=pics / "gap_display.txt")


def render_gap(run_dir: Path, pics: Path, log: Path) -> None:
    """Synthetic HDR photos of three gloss spheres, their Ward fit, the render layer's gap."""
    photos = run_dir / "glossfit" / "photos"
    run([PY, "-m", "stimuli", "synth-photos", str(photos), "--levels", "0,50,100", "--seed", "1"],
        log=log)
    run([PY, "-m", "stimuli", "fit-gloss", str(photos), "--out", str(run_dir / "glossfit")],
        log=log)
    run([PY, "-m", "analysis", "gap", "diagnose", "--layer", "render",
         "--real", str(run_dir / "glossfit"), "--sim", str(run_dir / "glossfit"),
         "--out", str(run_dir / "gap" / "render")], log=log, stdout=pics / "gap_render.txt")


def screenshots(run_dir: Path, pics: Path, log: Path) -> None:
    """The gap reports as a browser shows them (the analysis report's is taken in ``analysis``)."""
    for html in sorted((run_dir / "gap").glob("*/index.html")):
        screenshot(html, pics / f"gap_{html.parent.name}.png")


STEPS = (calibration, stimuli, session, analysis, gap, render_gap)


def _cpu_s() -> float:
    """CPU seconds (user + system) of this process and its finished children: the cost that
    does not depend on how busy the machine is."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "_generated")
    args = parser.parse_args(argv)
    pics = args.out
    if pics.exists():
        shutil.rmtree(pics)
    run_dir = pics / "run"
    run_dir.mkdir(parents=True)
    log = run_dir / "pipeline.log"
    t0, c0 = time.monotonic(), _cpu_s()
    for step in (*STEPS, screenshots):
        t, c = time.monotonic(), _cpu_s()
        step(run_dir, pics, log)
        print(f"make_pictures: {step.__name__:12s} {time.monotonic() - t:6.1f} s wall "
              f"{_cpu_s() - c:6.1f} s CPU", flush=True)
    for text in pics.glob("*.txt"):  # the run folder's path, as a reader's would read
        text.write_text(text.read_text().replace(str(run_dir), "out/docs-run"))
    print(f"make_pictures: all steps   {time.monotonic() - t0:6.1f} s wall "
          f"{_cpu_s() - c0:6.1f} s CPU -> {pics}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
