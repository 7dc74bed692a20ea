"""Several layers at once: the carrying layer, the combined report, argument errors."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap import GapError
from analysis.gap.__main__ import main
from analysis.gap.layers import parse_layer_paths
from analysis.gapbench import inject
from studydesign import load_design


def test_all_layers_names_the_injected_one(tmp_path, capsys):
    rng = np.random.default_rng(5)
    design = load_design()
    inject.write_sessions(inject.simulate_sessions(design, 2, rng), tmp_path / "obs_real")
    inject.write_sessions(inject.simulate_sessions(design, 2, rng), tmp_path / "obs_sim")
    inject.write_calibration(rng, tmp_path / "cal")
    inject.write_readings(inject.simulate_readings(rng, "black_offset", 0.05), tmp_path / "read")
    inject.write_render_fit(tmp_path / "fit", rng)
    real = (f"observer={tmp_path / 'obs_real'},display={tmp_path / 'read'},"
            f"render={tmp_path / 'fit'}")
    sim = f"observer={tmp_path / 'obs_sim'},display={tmp_path / 'cal'}"
    assert main(["diagnose", "--layer", "all", "--real", real, "--sim", sim,
                 "--out", str(tmp_path / "rep")]) == 0
    out = capsys.readouterr().out
    assert "carried by the display layer" in out and "black_offset" in out
    page = (tmp_path / "rep" / "index.html").read_text()
    assert "display/localisation.png" in page and "render layer" in page


def test_layer_paths_errors():
    with pytest.raises(GapError, match="LAYER=PATH"):
        parse_layer_paths("optics=/x")
    assert set(parse_layer_paths("display=/a, render=/b")) == {"display", "render"}


def _diag(layer, gap, ci, *, steps=(), verdict="unexplained", remaining=None):
    from analysis.gap.engine import Diagnosis

    return Diagnosis(layer=layer, ranking=(), steps=steps, verdict=verdict, gap_before=gap,
                     gap_after=gap, shrink_abs=0.0, shrink_abs_ci=(0.0, 0.0), shrink_pct=0.0,
                     shrink_pct_ci=(0.0, 0.0), seed=0, gap_before_ci=ci, remaining=remaining)


def test_a_layer_whose_own_verdict_is_no_gap_does_not_carry_one():
    """Above its floor but no worse than its ceiling (the demo's fitted observer) is no gap."""
    from analysis.gap.layers import which_layer

    observer = _diag("observer", 0.388, (0.30, 0.47), verdict="inconclusive",
                     remaining={"gap": -0.04, "ci": (-0.12, 0.02), "significant": False})
    render = _diag("render", 1.34, (1.18, 1.53), steps=("clearcoat",), verdict="clearcoat",
                   remaining={"gap": 0.0, "ci": (-0.01, 0.01), "significant": False})
    out = which_layer({"observer": observer, "render": render})
    assert out["layer"] == "render" and out["carrying"] == ["render"]
    assert "observer" not in out["text"]
    flagged = _diag("observer", 0.388, (0.30, 0.47),
                    remaining={"gap": 0.2, "ci": (0.1, 0.3), "significant": True})
    assert which_layer({"observer": flagged, "render": render})["carrying"] == ["render",
                                                                               "observer"]
