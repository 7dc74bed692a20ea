"""The blind generators (bench/blind/, issue 43 item 3) write effects of the size they say.

Each new case asks for its effect in the layer's tolerance (design.toml [gap]: observer 0.25
slider units, display 1 % of luminance, render 1 % of the photos' RMS). The size is recomputed
here from the files alone, against the same seed's no-effect case (observer ``none``, display
``clean``, render ``ward``), by the measure the tolerance names, and must lie within 20 % of
the multiple asked; the no-effect cases must carry no effect at all. The generators are loaded
by path: they are scripts that import nothing of the project.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

BLIND = Path(__file__).resolve().parents[2] / "bench" / "blind"


def load(name):
    spec = importlib.util.spec_from_file_location(f"blind_{name}", BLIND / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def obs_gen():
    return load("observer_gen")


@pytest.fixture(scope="module")
def disp_gen():
    return load("display_gen")


@pytest.fixture(scope="module")
def ren_gen():
    return load("render_gen")


def read_settings(folder):
    """{(participant, stimulus_id, session): (gloss, depth)} of a session folder."""
    out = {}
    for path in sorted((Path(folder) / "sessions").glob("*.csv")):
        with open(path, newline="") as fh:
            for row in csv.DictReader(fh):
                key = (row["participant"], row["stimulus_id"], row["session"])
                out[key] = (float(row["gloss_match"]), float(row["depth_match"]))
    return out


def observer_size(case_dir, none_dir):
    """RMS over trials of the (gloss, depth) distance, slider units, from the CSVs."""
    a, b = read_settings(case_dir / "real"), read_settings(none_dir / "real")
    assert a.keys() == b.keys()
    d = np.array([np.subtract(a[k], b[k]) for k in a])
    return float(np.sqrt(np.mean((d ** 2).sum(axis=1))))


@pytest.fixture(scope="module")
def observer_none(obs_gen, tmp_path_factory):
    out = tmp_path_factory.mktemp("obs") / "none"
    obs_gen.generate("none", 5, out, participants=3)
    return out


@pytest.mark.parametrize("case", ["rest_drift", "highlight_depth", "slider_swap",
                                  "gloss_depth", "illum_depth"])
@pytest.mark.parametrize("multiple", [0.5, 2.0])
def test_observer_case_has_the_size_asked(obs_gen, observer_none, tmp_path, case, multiple):
    truth = obs_gen.generate(case, 5, tmp_path, participants=3, multiple=multiple)
    from_files = observer_size(tmp_path, observer_none) / 0.25
    assert from_files == pytest.approx(multiple, rel=0.2)
    assert truth["size_in_tolerances"] == pytest.approx(from_files, rel=0.01)


def test_observer_none_is_no_effect(obs_gen, observer_none, tmp_path):
    truth = json.loads((observer_none / "truth.json").read_text())
    assert truth["size"] == 0.0
    assert all(p["label_pull_fraction"] == p["serial_pull_fraction"] == 0.0
               for p in truth["real"].values())
    # The same seed's effect cases keep none's participants: the full-size data's first three
    # are none's three, setting for setting.
    obs_gen.generate("none", 5, tmp_path, participants=6)
    six, three = read_settings(tmp_path / "real"), read_settings(observer_none / "real")
    assert {k: six[k] for k in three} == three


def read_readings(path):
    with open(path, newline="") as fh:
        return [(float(r["luminance_cd_m2"]), r["x_norm"], r["y_norm"], r["level"], r["repeat"])
                for r in csv.DictReader(fh)]


@pytest.mark.parametrize("case", ["gamma_tilt", "apl_loading", "offset_warmup"])
@pytest.mark.parametrize(("multiple", "run"), [(0.5, "full"), (2.0, "short")])
def test_display_case_has_the_size_asked(disp_gen, tmp_path, case, multiple, run):
    truth = disp_gen.generate(case, 5, tmp_path / case, run=run, multiple=multiple)
    disp_gen.generate("clean", 5, tmp_path / "clean", run=run)
    a = read_readings(tmp_path / case / "check.csv")
    b = read_readings(tmp_path / "clean" / "check.csv")
    assert [r[1:] for r in a] == [r[1:] for r in b]  # the same readings, in the same order
    la, lb = np.array([r[0] for r in a]), np.array([r[0] for r in b])
    white = truth["display"]["offset_cd_m2"] + truth["display"]["gain_cd_m2"]
    keep = lb > 0.05 * white
    from_files = 100.0 * np.sqrt(np.mean(((la[keep] - lb[keep]) / lb[keep]) ** 2))
    assert from_files == pytest.approx(multiple, rel=0.2)
    assert truth["size_in_tolerances"] == pytest.approx(multiple, rel=0.01)


def test_display_clean_is_no_effect(disp_gen, tmp_path):
    truth = disp_gen.generate("clean", 5, tmp_path, run="short")
    assert truth["size"] == 0.0 and truth["effect"] == {}
    assert len(read_readings(tmp_path / "check.csv")) == 9 * 5 * 2  # the short run


def read_png(path):
    """Codes of a PNG written by render_gen's encoder (no filtering), (h, w[, 3])."""
    data = Path(path).read_bytes()
    pos, idat, ihdr = 8, b"", None
    while pos < len(data):
        n, kind = struct.unpack(">I", data[pos:pos + 4])[0], data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + n]
        ihdr = struct.unpack(">IIBBBBB", body) if kind == b"IHDR" else ihdr
        idat += body if kind == b"IDAT" else b""
        pos += 12 + n
    w, h, depth, colour = ihdr[:4]
    ch = 3 if colour == 2 else 1
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, -1)[:, 1:]
    codes = raw.copy().view(">u2" if depth == 16 else "u1").astype(float)
    return codes.reshape(h, w, ch)


def render_size(case_dir, none_dir, heldout):
    """% of the held-out photos' RMS over the ball, from the PNGs: photon and read noise
    (variance = code + 16 per channel, 1 e-/code) subtracted from the squared differences."""
    mask = read_png(case_dir / "mask.png")[..., 0] > 0
    num = den = 0.0
    for k in heldout:
        a = read_png(case_dir / "images" / f"{k:03d}.png")[mask]
        b = read_png(none_dir / "images" / f"{k:03d}.png")[mask]
        ok = (a.max(-1) < 65535) & (b.max(-1) < 65535)
        a, b = a[ok], b[ok]
        var_a, var_b = (a + 16.0).sum(-1) / 9.0, (b + 16.0).sum(-1) / 9.0
        num += np.sum((a.mean(-1) - b.mean(-1)) ** 2 - var_a - var_b)
        den += np.sum(b.mean(-1) ** 2 - var_b)
    return 100.0 * np.sqrt(max(num, 0.0) / den)


@pytest.mark.parametrize("case", ["interreflection", "lens_flare"])
@pytest.mark.parametrize("multiple", [1.0, 2.0])
def test_render_case_has_the_size_asked(ren_gen, tmp_path, case, multiple):
    truth = ren_gen.generate(case, 5, tmp_path / case, n_half=6, multiple=multiple)
    ren_gen.generate("ward", 5, tmp_path / "ward", n_half=6)
    from_files = render_size(tmp_path / case, tmp_path / "ward", range(7, 13))
    assert from_files == pytest.approx(multiple, rel=0.2)
    assert truth["size_in_tolerances"] == pytest.approx(multiple, rel=0.01)


def test_render_ward_is_no_effect(ren_gen, tmp_path):
    truth = ren_gen.generate("ward", 5, tmp_path, n_half=6)
    assert truth["size"] == 0.0 and truth["effect"] == {}
    assert set(truth["material"]) == {"rho_d", "rho_s", "alpha"}  # Ward's own, nothing added
