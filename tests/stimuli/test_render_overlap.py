"""The PNG pass beside the renders, and the plan in the pace of the machine it runs on."""

from __future__ import annotations

import json

from stimuli import load_manifest
from stimuli.__main__ import main
from stimuli.runplan import measured_pace_text


def test_a_light_field_is_tone_mapped_while_the_next_one_renders(tmp_path, capsys,
                                                                  mitsuba_variant):
    """In-process render of the preview set (2 light fields x 2 arrays x 2 gloss, 16 px): the
    first light field's PNGs are begun before the render pass ends (the last one's cannot be),
    every image is listed once and verifies, and the pace measured on this machine's images is
    printed once the first group (which compiles the kernels) is past."""
    out = tmp_path / "r"
    rc = main(["render", "--set", "preview", "--out", str(out), "--workers", "0", "--size", "16",
               "--spp", "4", "--no-progress"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    summary = json.loads(captured.out)
    m = load_manifest(out)
    order = list(dict.fromkeys(m["light_field"]))
    assert summary["tonemapped_while_rendering"] == order[:1]
    assert len(m) == 8 and m["stimulus_id"].is_unique and summary["png_written"] == 8
    assert "pace measured here on 2 images" in captured.err
    assert main(["verify", str(out)]) == 0
    capsys.readouterr()
    # resumed: nothing rendered or written again, nothing tone-mapped beside the renders
    assert main(["render", "--set", "preview", "--out", str(out), "--workers", "0", "--size",
                 "16", "--spp", "4", "--no-progress"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["rendered"] == 0 and again["png_skipped"] == 8
    assert again["tonemapped_while_rendering"] == []


def test_measured_pace_fits_seconds_per_sample_and_per_image():
    """Images of 1 s + 1 us per pixel sample: the line gives 1000 ms per megasample, 1.00 s
    per image, and the images left at that pace over the workers."""
    size = 100
    timed = [(1.0 + 1e-6 * size * size * n, n) for n in (10, 20, 40, 80)]
    text = measured_pace_text(timed, size, [100] * 36, n_workers=2)
    assert "1000.0 ms per megasample + 1.00 s per image" in text
    assert "36 images left: about 36 s on 2 worker(s)" in text  # 36 x (1 + 1) s / 2


def test_the_cleanup_after_the_workers_pass_leaves_a_png_being_written(tmp_path):
    """A PNG is written (temporary file, then renamed) on the tone-map thread while the render
    pass ends; the pass's cleanup of the workers' stale temporaries once removed it mid-write
    ("No such file or directory: .../png/indoor/indoor_g02_d02.png", a --workers 2 render in
    CI). Only the workers' EXR temporaries are stale there."""
    from labfiles import atomic_open
    from stimuli.pipeline import _remove_stale_temporaries

    (tmp_path / "exr").mkdir()
    stale_exr = tmp_path / "exr" / ".a.exr.tmp-1-2"
    stale_exr.write_bytes(b"killed worker")
    png = tmp_path / "png" / "indoor" / "indoor_g02_d02.png"
    png.parent.mkdir(parents=True)
    with atomic_open(png, "wb") as fh:
        fh.write(b"png bytes")
        _remove_stale_temporaries(tmp_path, subs=("exr",))  # as the workers' pass ends
    assert png.read_bytes() == b"png bytes"
    assert not stale_exr.exists()
