"""Several layers at once: the carrying layer, the combined report, argument errors."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap import GapError, inject
from analysis.gap.__main__ import main
from analysis.gap.layers import parse_layer_paths
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
