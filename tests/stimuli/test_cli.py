"""`python -m stimuli`: render (real Mitsuba renders, tiny), resume after a kill, bad input, export.

Renders here are 32 px at 4 spp so the whole file runs in well under a minute on 2 cores.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from stimuli import load_manifest, verify_manifest
from stimuli.__main__ import main
from stimuli.illumination import read_exr

TINY = ["--size", "32", "--spp", "4", "--no-progress"]


def _env():
    return dict(os.environ, DRJIT_LIBLLVM_PATH=os.environ.get(
        "DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"))


def test_render_writes_manifest_exr_png(tmp_path, design, capsys, mitsuba_variant):
    out = tmp_path / "r"
    rc = main(["render", "--set", "preview", "--filter", "illumination=indoor", "--out", str(out),
               "--workers", "0", *TINY])
    assert rc == 0, capsys.readouterr().err
    capsys.readouterr()
    m = load_manifest(out)
    assert len(m) == 4 and verify_manifest(out, kinds=("png", "exr")) == []
    row = m.iloc[0]
    assert row["variant"] == mitsuba_variant and row["width_px"] == 32 and row["spp"] == 4
    assert row["image_width_cm"] > design.array.extent_cm
    assert row["distance_cm"] == design.display.viewing_distance_cm
    exr = read_exr(out / row["exr_path"])
    assert exr.shape == (32, 32) and exr.dtype == np.float32 and exr.min() >= 0
    png = np.asarray(Image.open(out / row["png_path"]))
    assert png.dtype == np.uint8 and png.shape == (32, 32) and png.max() > png.min()
    assert m["tonemap_lmax"].nunique() == 1  # one tone curve per illumination condition
    # glossier stimuli reach brighter highlights
    g = m.sort_values("gloss_level")
    peaks = [np.percentile(read_exr(out / p), 99) for p in g["exr_path"]]
    assert max(peaks[2:]) > max(peaks[:2])
    # a second run finds everything done
    rc = main(["render", "--set", "preview", "--filter", "illumination=indoor", "--out", str(out),
               "--workers", "0", *TINY])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0 and summary["rendered"] == 0 and summary["png_skipped"] == 4
    # a PNG changed after recording is never silently replaced
    (out / row["png_path"]).write_bytes(b"x")
    rc = main(["render", "--set", "preview", "--filter", "illumination=indoor", "--out", str(out),
               "--workers", "0", *TINY])
    assert rc == 1 and "never overwritten" in capsys.readouterr().err


@pytest.mark.slow
def test_killed_run_resumes_and_keeps_finished_work(tmp_path):
    """SIGKILL the renderer mid-run; the re-run renders only what is missing, no file half-written."""
    out = tmp_path / "k"
    cmd = [sys.executable, "-m", "stimuli", "render", "--set", "preview", "--out", str(out),
           "--workers", "0", *TINY]
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    log = out / "renders.csv"
    deadline = time.time() + 120
    while time.time() < deadline:
        if log.is_file() and len(log.read_text().splitlines()) >= 3:  # header + 2 EXRs
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    n_before = len(pd.read_csv(log))
    assert 2 <= n_before < 8 and not (out / "manifest.csv").exists()
    res = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["render_skipped"] == n_before and summary["rendered"] == 8 - n_before
    assert verify_manifest(out, kinds=("png", "exr")) == []
    assert not list(out.rglob(".*tmp*"))


@pytest.mark.slow
def test_dask_local_cluster_render(tmp_path, capsys):
    out = tmp_path / "d"
    rc = main(["render", "--set", "preview", "--filter", "depth_level=2", "--out", str(out),
               "--workers", "2", *TINY])
    assert rc == 0, capsys.readouterr().err
    assert len(load_manifest(out)) == 4 and verify_manifest(out) == []


def _bad(tmp_path):
    bad_json = tmp_path / "cal.json"
    bad_json.write_text("{not json")
    bad_table = tmp_path / "gloss.csv"
    bad_table.write_text("gloss_pct,rho_d\n0,0.5\n")
    src = (tmp_path / "design.toml")
    from studydesign import default_design_path

    indoor = '"aerodynamics_workshop_512x256.hdr"'  # the indoor condition's probe, named first
    src.write_text(default_design_path().read_text().replace(indoor, '"nowhere.exr"', 1))
    return [
        (["--set", "nonsense"], "unknown stimulus set"),
        (["--gloss-table", str(tmp_path / "missing.csv")], "missing.csv not found"),
        (["--gloss-table", str(bad_table)], "lacks columns"),
        (["--calibration", str(tmp_path / "none.json")], "none.json not found"),
        (["--calibration", str(bad_json)], "not valid JSON"),
        (["--filter", "depth_level=77"], "select no stimuli"),
        (["--design", str(src)], "nowhere.exr"),
    ]


def test_bad_input_gives_clear_errors(tmp_path, capsys, mitsuba_variant):
    for extra, match in _bad(tmp_path):
        design = extra[:2] if extra[0] == "--design" else []
        rest = extra[2:] if design else extra
        args = [*design, "render", "--out", str(tmp_path / "o"), "--workers", "0", *TINY, *rest]
        if "--set" not in rest:
            args += ["--set", "preview"]
        assert main(args) == 1, extra
        err = capsys.readouterr().err
        assert match in err, (extra, err)
    assert not (tmp_path / "o" / "manifest.csv").exists()


def test_export_print_writes_a_watertight_stl(tmp_path, capsys):
    out = tmp_path / "d5.stl"
    assert main(["export-print", "--depth-level", "5", "--spacing-cm", "0.1", str(out)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["watertight"].startswith("closed") and out.stat().st_size == 84 + 50 * info["faces"]
    assert main(["export-print", "--depth-level", "42", str(out)]) == 1
    assert "not a depth level" in capsys.readouterr().err


@pytest.mark.slow
def test_imagestats_slice_renders_22_distinct_captures_each_tone_mapped_alone(
        tmp_path, design, capsys, mitsuba_variant):
    """The slice crosses all 22 light fields: the manifest names 22 distinct probe files with
    their checksums, and tonemaps.csv holds one tone curve per light field, the one its PNGs
    were mapped with (L_max from that light field's images only)."""
    from stimuli.illumination import probe_path
    from stimuli.manifest import sha256_file

    out = tmp_path / "slice"
    rc = main(["render", "--set", "imagestats_slice", "--out", str(out), "--workers", "0",
               "--size", "16", "--spp", "1", "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    m = load_manifest(out)
    assert len(m) == 44 and m["light_field"].nunique() == 22
    probes = m.groupby("light_field")[["envmap", "envmap_sha256"]].agg(set)
    assert (probes.map(len) == 1).all().all()  # one probe per light field
    files = {next(iter(e)) for e in probes["envmap"]}
    assert len(files) == 22 and (m["rotation_deg"] == 0).all()
    for row in m.drop_duplicates("envmap").itertuples():
        assert row.envmap_sha256 == sha256_file(probe_path(row.envmap))
    curves = pd.read_csv(out / "tonemaps.csv").set_index("light_field")
    assert len(curves) == 22 and curves["n_images"].eq(2).all()
    lmax = m.groupby("light_field")["tonemap_lmax"].agg(["min", "max"])
    assert (lmax["min"] == lmax["max"]).all()
    np.testing.assert_allclose(curves.loc[lmax.index, "tonemap_lmax"], lmax["min"], rtol=1e-9)
    assert curves["tonemap_lmax"].nunique() == 22  # each fitted to its own light field
    for lf, c in curves.iterrows():
        expected = max(np.percentile(read_exr(out / p), 99.9)
                       for p in m.loc[m["light_field"] == lf, "exr_path"])
        assert c["tonemap_lmax"] == pytest.approx(expected, rel=1e-6)
        assert c["knee_luminance"] == pytest.approx(design.tonemap.linear_fraction * expected)
    assert set(curves["envmap"]) == files


def _stl_vertices_as_a_slicer_reads_them(path) -> np.ndarray:
    """Binary STL per its specification: 80-byte header, uint32 triangle count, then per
    triangle 12 little-endian float32 (normal, three vertices) and a uint16. No unit field:
    Cura, PrusaSlicer and GrabCAD Print take the numbers as millimetres."""
    import struct

    data = path.read_bytes()
    (n,) = struct.unpack_from("<I", data, 80)
    assert len(data) == 84 + 50 * n
    rec = np.frombuffer(data, dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")],
                        count=n, offset=84)
    return rec["v"].reshape(-1, 3)


@pytest.mark.parametrize("units, per_cm", [(None, 10.0), ("mm", 10.0), ("cm", 1.0)])
def test_export_print_is_true_size_in_a_slicer(tmp_path, capsys, design, units, per_cm):
    """STL was written in cm, so a slicer printed the arrays a tenth of their size (the design's
    5 cm array square 5 mm wide); millimetres are the default now."""
    from stimuli.geometry import draw_array, stimulus_seed

    out = tmp_path / "d5.stl"
    extra = [] if units is None else ["--units", units]
    assert main(["export-print", "--depth-level", "5", "--spacing-cm", "0.1", *extra,
                 str(out)]) == 0
    info = json.loads(capsys.readouterr().out)
    v = _stl_vertices_as_a_slicer_reads_them(out)
    width, depth, height = v.max(axis=0) - v.min(axis=0)
    geometry = draw_array(design, float(design.depth.cm(5)), stimulus_seed(5, 0))
    want_cm = 2 * (geometry.half_extent_cm + 0.5)  # the array and its 0.5 cm margin
    assert width == pytest.approx(want_cm * per_cm, abs=0.1 * per_cm)
    assert depth == pytest.approx(want_cm * per_cm, abs=0.1 * per_cm)
    if per_cm == 10.0:
        assert width > 10 * design.array.extent_cm  # at least 50 mm, as the rendered array
    assert info["units"] == (units or "mm")
    assert info["size"] == f"{width:.1f} x {depth:.1f} x {height:.1f} {units or 'mm'}"
    assert out.read_bytes()[:80].rstrip().endswith(f"units {units or 'mm'}".encode())


def test_resume_under_another_probe_is_refused_before_anything_is_replaced(tmp_path, capsys,
                                                                           mitsuba_variant):
    """A folder rendered under one probe, resumed with a design whose condition now names
    another capture, used to count its EXRs as done (same levels, spp and size) and keep them
    silently; now the run stops, naming the probe, and replaces nothing."""
    from studydesign import default_design_path

    out = tmp_path / "r"
    args = ["render", "--set", "preview", "--filter", "illumination=indoor", "--limit", "1",
            "--out", str(out), "--workers", "0", *TINY]
    assert main(args) == 0, capsys.readouterr().err
    capsys.readouterr()
    exr = next((out / "exr").rglob("*.exr"))
    before = exr.read_bytes()
    other = tmp_path / "design.toml"
    other.write_text(default_design_path().read_text().replace(
        '"aerodynamics_workshop_512x256.hdr"', '"lebombo_512x256.hdr"', 1).replace(
        "scale = 0.976623", "scale = 1.11829", 1))  # lebombo's own scale (lightfields.tsv)
    assert main(["--design", str(other), *args]) == 1
    err = capsys.readouterr().err
    assert "another light probe" in err and "new --out folder" in err
    assert exr.read_bytes() == before
