"""Claim: the session app's own work per frame is under half a frame of the CRT (85 Hz), and the
next stimulus is ready for the first flip after a response.

Measured in the real session window (``experiment.display.SessionDisplay``) with all 81 textures
of a session preloaded, stimuli at the lab's size (8 cm, 512 px PNGs), both sliders set:

* per frame: drawing the trial screen (stimulus, two Sliders, their tick labels and titles as
  one texture captured at the start),
  timed on the CPU and to ``glFinish`` (the GPU done), without the flip;
* per trial transition: what happens between a response and the next onset flip: the CSV row
  and slider histories appended and fsynced, the sliders reset, the next stimulus drawn (a
  texture swap) up to ``glFinish``;

each divided by the frame budget 1 / refresh (the design's nominal 85 Hz: 11.76 ms). Under Xvfb
GL runs in software (llvmpipe) on a shared CPU, so the ratios here are an upper bound; run the
script on the lab machine for the real figure (protocol.md, "on-hardware timing check").

Usage (needs an X display)::

    xvfb-run -a -s "-screen 0 1280x1024x24" .venv/bin/python bench/experiment_frame_cost.py
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from experiment import SessionWriter, load_or_create_plan
from experiment.checks import check_calibration, check_stimuli
from experiment.display import SessionDisplay
from studydesign import load_design
from tests.experiment.fixtures import make_calibration, make_manifest


def _ms(v) -> str:
    v = np.asarray(v) * 1000
    return f"median {np.median(v):6.2f} ms, p95 {np.percentile(v, 95):6.2f} ms"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--transitions", type=int, default=40)
    args = ap.parse_args(argv)
    design = load_design()
    budget = design.display.frame_s
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        plan = load_or_create_plan(design, "BENCH", tmp / "data")
        rows = plan[plan["session"] == 1].reset_index(drop=True)
        manifest = make_manifest(tmp / "stim", design, stimulus_ids=set(rows["stimulus_id"]),
                                 size_px=512)
        cal = check_calibration(make_calibration(tmp / "cal", design), design, max_age_days=30)
        stim = check_stimuli(manifest, rows)
        from pyglet import gl

        with SessionDisplay(design, cal, stim.frame, fast=True) as disp, \
                SessionWriter(tmp / "data", "BENCH", 1, background_fsync=True) as writer:
            print(f"preload of {disp.info['n_textures']} textures: "
                  f"{disp.info['preload_s'] * 1000:.0f} ms (before the first trial)")
            disp.gloss_slider.rating = 4.2
            disp.depth_slider.rating = 7.7
            ids = list(rows["stimulus_id"])
            cpu, gpu, stim_only = [], [], []
            for k in range(args.frames):
                disp.flip()
                t0 = time.perf_counter()
                disp.draw_trial(ids[k % len(ids)])
                t1 = time.perf_counter()
                gl.glFinish()
                t2 = time.perf_counter()
                cpu.append(t1 - t0)
                gpu.append(t2 - t0)
                disp.flip()
                t0 = time.perf_counter()
                disp.textures[ids[k % len(ids)]].draw()
                gl.glFinish()
                stim_only.append(time.perf_counter() - t0)
            row = {c: 0 for c in writer_columns()}
            hist = {"gloss_history": [[4.2, 1.0]], "depth_history": [[7.7, 2.0]]}
            trans, write, reset, draw, sync_write, later = [], [], [], [], [], []
            with SessionWriter(tmp / "data", "BENCH", 2) as sync_writer:
                for k in range(args.transitions):
                    t0 = time.perf_counter()
                    sync_writer.append({**row, "trial": k + 1}, sliders=hist)
                    sync_write.append(time.perf_counter() - t0)
            for k in range(args.transitions):
                disp.flip()
                t0 = time.perf_counter()
                writer.append({**row, "trial": k + 1}, sliders=hist)
                t1 = time.perf_counter()
                disp.reset_sliders()
                t2 = time.perf_counter()
                disp.draw_trial(ids[(k + 1) % len(ids)])
                gl.glFinish()
                t3 = time.perf_counter()
                writer.wait()
                later.append(time.perf_counter() - t0)
                trans.append(t3 - t0)
                write.append(t1 - t0)
                reset.append(t2 - t1)
                draw.append(t3 - t2)
            # The Slider's own TextBox2 tick labels, for comparison (what the app does not use).
            from psychopy import visual

            own = visual.Slider(disp.win, ticks=list(design.slider.ticks),
                                labels=[str(t) for t in design.slider.ticks], granularity=0,
                                size=(disp.layout.slider_width_px, disp.layout.slider_height_px),
                                pos=(0, disp.layout.gloss_y_px), units="pix", style="rating",
                                font=disp.info["font"], autoLog=False)
            own.rating = 4.2
            # One slider and its labels, three ways: CPU time of the draw calls, then to glFinish.
            variants = {
                "labels as one texture (the app)": lambda: disp.static_layer.draw(),
                "11 TextStim labels": lambda: [lab.draw() for lab in
                                               disp.tick_labels[:len(design.slider.ticks)]],
            }
            cost = {name: ([], []) for name in [*variants, "own TextBox2 labels"]}
            for _ in range(args.frames // 2):
                for name, extra in variants.items():
                    disp.flip()
                    t0 = time.perf_counter()
                    disp.gloss_slider.draw()
                    extra()
                    t1 = time.perf_counter()
                    gl.glFinish()
                    cost[name][0].append(t1 - t0)
                    cost[name][1].append(time.perf_counter() - t0)
                disp.flip()
                t0 = time.perf_counter()
                own.draw()
                t1 = time.perf_counter()
                gl.glFinish()
                cost["own TextBox2 labels"][0].append(t1 - t0)
                cost["own TextBox2 labels"][1].append(time.perf_counter() - t0)
    print(f"frame budget at {design.display.nominal_refresh_hz:g} Hz: {budget * 1000:.2f} ms")
    rows_out = [("trial screen, CPU (draw calls)", cpu), ("trial screen, to glFinish", gpu),
                ("stimulus alone, to glFinish", stim_only),
                ("CSV row + histories appended, fsync waited for", sync_write),
                ("  of which: row + histories written (fsync on a thread)", write),
                ("  of which: sliders reset", reset),
                ("  of which: next trial drawn (texture swap), glFinish", draw),
                ("response -> next screen ready (all of the above)", trans),
                ("response -> next screen ready and row fsynced", later),
                *[(f"one slider, {name}, {kind}", cost[name][k])
                  for name in cost for k, kind in enumerate(("CPU", "to glFinish"))]]
    for name, v in rows_out:
        print(f"{name:55s} {_ms(v)}  / frame: median {np.median(v) / budget:4.2f}, "
              f"p95 {np.percentile(v, 95) / budget:4.2f}")
    app = np.median(cost["labels as one texture (the app)"][0])
    print("slider + labels, CPU time relative to the app's (median): " + ", ".join(
        f"{name} {np.median(v[0]) / app:.1f}x" for name, v in cost.items()))
    for what, v in (("per-frame cost (CPU)", cpu), ("per-frame cost (to glFinish)", gpu),
                    ("response -> next screen ready", trans)):
        print(f"{what} / frame budget: median {np.median(v) / budget:.2f}, "
              f"p95 {np.percentile(v, 95) / budget:.2f}")
    print("targets: per frame < 0.5; transition < 1 - per-frame (next stimulus on the first flip "
          "after a response). Under Xvfb, GL is software (llvmpipe) on a shared CPU: an upper bound")
    return 0


def writer_columns():
    from experiment import SESSION_COLUMNS

    return SESSION_COLUMNS


if __name__ == "__main__":
    sys.exit(main())
