"""``python -m stimuli synth-photos`` and ``fit-gloss`` through the package's real CLI."""

from __future__ import annotations

import json

import pandas as pd

from stimuli.__main__ import main


def test_synth_then_fit_with_clipped_photos_in_other_units(tmp_path, capsys):
    photos = tmp_path / "glossfit" / "photos"
    rc = main(["synth-photos", str(photos), "--material", "ward", "--levels", "0,100",
               "--effects", "clipping:quantile=0.9995", "--spp", "16", "--seed", "4",
               "--exposure", "1.5"])
    assert rc == 0
    assert json.loads((photos / "truth.json").read_text())["effects"] == {
        "clipping": {"quantile": 0.9995}}
    # the fit may write beside the photos (as the demo does), never over its own output
    rc = main(["fit-gloss", str(photos), "--out", str(tmp_path / "glossfit"), "--spp", "16"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    fits = pd.read_csv(tmp_path / "glossfit" / "fits.csv")
    assert (fits["clipped_fraction"] > 0).all()
    assert fits["warnings"].str.contains("clipped").all()
    assert "clipped" in out.err and "missing gloss levels" in out.err
    assert "not in the same units" in out.err  # photos exposed 1.5x the panorama
    assert json.loads((tmp_path / "glossfit" / "fit.json").read_text())["versions"]["variant"] \
        == "llvm_ad_rgb"
    assert (tmp_path / "glossfit" / "gloss_table.csv").exists()
    rc = main(["fit-gloss", str(photos), "--out", str(tmp_path / "glossfit")])
    assert rc == 1 and "already holds" in capsys.readouterr().err


def test_cli_errors_name_the_problem(tmp_path, capsys):
    assert main(["fit-gloss", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 1
    assert "is not a folder" in capsys.readouterr().err
    assert main(["synth-photos", str(tmp_path / "s"), "--levels", "15"]) == 1
    assert "no gloss levels of the design" in capsys.readouterr().err
    assert main(["synth-photos", str(tmp_path / "s"), "--effects", "bloom"]) == 1
    assert "unknown effect" in capsys.readouterr().err
