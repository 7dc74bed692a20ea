"""The render layer on a panorama photo set in two lightings: fit one, diagnose the other."""

from __future__ import annotations

import json
import math

from analysis.gap.__main__ import main as gap_main
from stimuli.glossfit.cli import main as glossfit_main
from stimuli.glossfit.lightings import synth_lightings, turned_room
from stimuli.glossfit.photoset import PhotoSetup
from stimuli.glossfit.synth import room_panorama

#: A small set: the sphere 28 px across in 48 px photos (the fit's registration needs
#: background around it), Ward spheres (the fit's own model), no camera effects.
SETUP = PhotoSetup(camera_distance_cm=27.5, sphere_radius_cm=2.0, fov_deg=16.0,
                   resolution_px=(48, 48))


def test_a_lighting_held_out_of_a_panorama_set(tmp_path, capsys):
    """Ward spheres photographed in a room and in the room turned and dimmed: fitted in one,
    the fit predicts the other's photos about as well as its own (a prediction in the wrong
    room does not even register), the diagnosis reports the held-out misfit and names
    nothing."""
    from analysis.gap.render.ceiling import misfit_pct
    from analysis.gap.render.data import load_render

    room = room_panorama()
    s, fit, out = tmp_path / "set", tmp_path / "fit", tmp_path / "gap"
    synth_lightings(s, (50.0, 100.0), {"day": room, "lamp": turned_room(room)},
                    material="ward", effects={}, spp=64, setup=SETUP, seed=1)
    # Several lightings: the one to fit must be named.
    assert glossfit_main(["fit-gloss", str(s), "--out", str(tmp_path / "f0")]) == 1
    assert "--lights day" in capsys.readouterr().err
    assert glossfit_main(["fit-gloss", str(s), "--lights", "day", "--out", str(fit),
                          "--resolution", "32", "--spp", "32"]) == 0
    info = json.loads((fit / "fit.json").read_text())
    assert (info["lighting"], info["lightings"]) == ("day", ["day", "lamp"])
    assert gap_main(["diagnose", "--layer", "render", "--real", str(s), "--lights", "lamp",
                     "--sim", str(fit), "--out", str(out)]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert "held-out lighting lamp" in d["split"]
    assert not d["steps"]  # the fit's own model: nothing named
    assert set(d["loss_info"]["noise_a2_b"]) == {"gloss_050", "gloss_100", "gloss_050 (held out)",
                                                 "gloss_100 (held out)"}
    before, after = d["misfit_pct_before"], d["misfit_pct_after"]
    in_sample = misfit_pct(load_render(fit), [])
    assert math.isfinite(before) and after <= before + 1e-9
    assert before < 1.5 * in_sample, (before, in_sample)
    assert "held-out RMS misfit" in (out / "index.html").read_text()
    # The held-out lighting must be one the fit never saw.
    assert gap_main(["diagnose", "--layer", "render", "--real", str(s), "--lights", "day",
                     "--sim", str(fit), "--out", str(tmp_path / "g2")]) == 2
    assert "--lights day was fitted" in capsys.readouterr().err
