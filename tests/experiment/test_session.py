"""A whole simulated session through the real PsychoPy window under Xvfb, and its screenshot."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from PIL import Image

import experiment
from analysis.load import load_sessions
from calibration import load_calibration
from experiment import SESSION_COLUMNS, read_session
from experiment.display import plan_layout

from .conftest import run_app
from .fixtures import WIDTH_CM

pytestmark = pytest.mark.xvfb


@pytest.mark.slow
def test_full_simulated_session_through_the_window(session_files, design):
    f = session_files
    shot = f["root"] / "trial.png"
    res = run_app("run", "--participant", "P01", "--session", "1", "--stimuli", f["manifest"],
                  "--calibration", f["calibration"], "--data", f["data"], "--simulate",
                  "humanlike", "--fast", "--screenshot", shot, "--simulate-early-space", "0.05")
    assert res.returncode == 0, res.stderr
    data = read_session(f["data"] / "sessions" / "P01_s1.csv")
    n = design.sessions.trials_per_session
    assert tuple(data.columns) == SESSION_COLUMNS
    assert data["trial"].tolist() == list(range(1, n + 1))
    plan = experiment.load_or_create_plan(design, "P01", f["data"])
    assert data["stimulus_id"].tolist() == plan[plan["session"] == 1]["stimulus_id"].tolist()
    # The sliders recorded what the simulated hand aimed at, to the pixel.
    log = json.loads((f["data"] / "logs" / "P01_s1_run1.json").read_text())
    intended = np.array([log["simulated"]["intended"][str(t)] for t in data["trial"]])
    got = data[["gloss_match", "depth_match"]].to_numpy()
    cal = load_calibration(f["calibration"])
    lay = plan_layout(design, cal, pd.DataFrame({"image_width_cm": [WIDTH_CM],
                                                 "width_px": [64], "height_px": [64]}))
    scale_units_per_px = (design.slider.max - design.slider.min) / lay.slider_width_px
    clipped = np.clip(intended, design.slider.min, design.slider.max)
    assert np.abs(got - clipped).max() <= 1.01 * scale_units_per_px
    assert log["keyboard_backend"] == "ptb"
    assert log["n_textures"] == n
    assert log["frame_intervals"]["n"] > n
    assert log["response_to_next_onset"]["n"] == n - 1
    assert log["status"] == "complete"
    assert "no hardware gamma table" in log["gamma"]
    assert (data["rt_s"] > 0).all() and data["onset_s"].is_monotonic_increasing
    sliders = [json.loads(line) for line in
               (f["data"] / "sliders" / "P01_s1.jsonl").read_text().splitlines()]
    assert [s["trial"] for s in sliders] == list(range(1, n + 1))
    assert all(s["gloss_history"] and s["depth_history"] for s in sliders)
    assert (f["data"] / "logs" / "P01_s1_run1_frames.png").stat().st_size > 0
    loaded = load_sessions(f["data"], design)
    assert len(loaded.frame) == n
    _check_screenshot(shot, design, f["calibration"], data.iloc[0])


def _check_screenshot(path, design, calibration, first_row):
    """The stimulus at its physical size, both slider lines and both red markers where the
    recorded answers say."""
    img = np.asarray(Image.open(path).convert("RGB")).astype(int)
    h, w, _ = img.shape
    assert (w, h) == tuple(design.display.resolution_px)
    cal = load_calibration(calibration)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    green = (g > 150) & (r < 100) & (b < 120)
    _ys, xs = np.nonzero(green)
    px_per_cm = w / cal.width_cm
    # The PNG's 4-px dark border (of 64 px) lies inside the physical width.
    assert (xs.max() - xs.min() + 1) == pytest.approx(WIDTH_CM * px_per_cm * 56 / 64, abs=4)
    assert (xs.max() + xs.min()) / 2 == pytest.approx(w / 2, abs=2)
    lay = plan_layout(design, cal, pd.DataFrame({"image_width_cm": [WIDTH_CM],
                                                 "width_px": [64], "height_px": [64]}))
    red = (r > 200) & (g < 80) & (b < 80)
    white = (r > 200) & (g > 200) & (b > 200)
    x0 = w / 2 - lay.slider_width_px / 2
    for name, y_px in (("gloss", lay.gloss_y_px), ("depth", lay.depth_y_px)):
        row = round(h / 2 - y_px)
        band = slice(row - 12, row + 13)
        # the slider's line spans the slider width
        line_cols = np.nonzero(white[row - 2:row + 3].any(axis=0))[0]
        assert line_cols.max() - line_cols.min() == pytest.approx(lay.slider_width_px, abs=4)
        # one tick label under each tick (the labels are light text below the line)
        light = (r > 120) & (g > 120) & (b > 120)
        cols = np.nonzero(light[row + 6: row + 34].any(axis=0))[0]
        groups = 1 + int(np.sum(np.diff(cols) > 6)) if cols.size else 0
        assert groups == len(design.slider.ticks), f"{name}: {groups} tick labels"
        # one red marker, centred on the recorded answer
        _ry, rx = np.nonzero(red[band])
        assert rx.size > 20, f"no red marker on the {name} slider"
        value = first_row[f"{name}_match"]
        expect_x = x0 + (value - design.slider.min) / (design.slider.max - design.slider.min) \
            * lay.slider_width_px
        assert rx.mean() == pytest.approx(expect_x, abs=3)
    assert not red[: h // 2].any(), "red outside the slider rows"


def test_session_without_simulation_quits_on_escape(session_files, small_design_path):
    """The operator's path (no --simulate, no --fast): the refresh rate is measured (and, with
    no vsync under Xvfb, found unmeasurable: a warning), Esc pauses, Esc again quits (status
    3), nothing recorded is lost. Keys come from outside the app, as from a keyboard."""
    import subprocess
    import sys
    import time

    from experiment.simulate import XTestInput

    from .conftest import REPO, app_env

    f = session_files
    cmd = [sys.executable, "-m", "experiment", "--design", str(small_design_path), "run",
           "--participant", "H1", "--session", "1", "--stimuli", str(f["manifest"]),
           "--calibration", str(f["calibration"]), "--data", str(f["data"])]
    proc = subprocess.Popen(cmd, cwd=REPO, env=app_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    t_end = time.monotonic() + 90
    with XTestInput() as x:
        while proc.poll() is None and time.monotonic() < t_end:
            x.key("escape", True)
            time.sleep(0.05)
            x.key("escape", False)
            time.sleep(0.5)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 3, err
    assert "run the same command to continue" in err
    log = json.loads((f["data"] / "logs" / "H1_s1_run1.json").read_text())
    assert log["status"] == "quit" and "refresh_hz_measured" in log
    assert any("refresh rate" in w for w in log["warnings"])
    assert read_session(f["data"] / "sessions" / "H1_s1.csv").empty
