"""A synthetic rating study written as a lab's PsychoPy files are (a BOM, CRLF line ends, a
trailing comma on every line, a header split by an unquoted comma), with a study.toml: the
generator is written here, apart from experiment.rating_observer, so that a test of the fit
and the diagnosis does not check the model against itself."""

from __future__ import annotations

from pathlib import Path

import numpy as np

STUDY_TOML = """name = "synthetic rating study"
files = "*_ratings.csv"
[columns]
participant = "participant ID (two digits, e.g. 01)"
stimulus = "trials.thisIndex"
trial = "trials.thisN"
response = "rating"
rt_s = "decisionTime"
[response]
estimates = "true_gloss"
scale = [1, 6]
step = 1
[stimuli]
table = "stimuli.csv"
id = "stimulus"
"""


def write_study(folder: Path, rng: np.random.Generator, *, n_participants: int = 10,
                n_stimuli: int = 40, repeats: int = 3, stimulus_bias: float = 0.0,
                serial: float = 0.0, lapses: float = 0.0, serial_from: int = 0) -> Path:
    """Write the study into ``folder``; returns its study.toml. Effects (latent scale units):
    ``stimulus_bias`` the SD of a per-stimulus offset shared by all participants, ``serial``
    a pull toward the previous response, ``lapses`` a rate of uniform responses; the sequence
    and mixture effects only for participants numbered from ``serial_from`` on."""
    folder.mkdir(parents=True, exist_ok=True)
    gloss = np.round(rng.uniform(0.2, 1.0, n_stimuli), 3)
    bias = rng.normal(0.0, stimulus_bias, n_stimuli) if stimulus_bias else np.zeros(n_stimuli)
    lines = ["stimulus,image,true_gloss"] + [f"{k},img{k:03d}.png,{g}" for k, g in
                                            enumerate(gloss)]
    (folder / "stimuli.csv").write_bytes(("\r\n".join(lines) + "\r\n").encode())
    header = ("stimOne,trials.thisN,trials.thisIndex,rating,decisionTime,"
              "participant ID (two digits, e.g. 01),age,")
    for p in range(1, n_participants + 1):
        pid = f"{p:02d}"
        gain, offset = rng.normal(7.0, 1.5), rng.normal(3.3, 0.4)
        order = rng.permutation(np.repeat(np.arange(n_stimuli), repeats))
        rows, prev = [header], None
        on = p > serial_from
        for t, s in enumerate(order):
            mu = offset + gain * (gloss[s] - 0.6) + bias[s]
            if on and serial and prev is not None:
                mu += serial * (prev - mu)
            r = int(np.clip(np.round(mu + rng.normal(0.0, 0.9)), 1, 6))
            if on and rng.random() < lapses:
                r = int(rng.integers(1, 7))
            prev = r
            rows.append(f"img{s:03d}.png,{t},{s},{r},{rng.gamma(4.0, 1.0):.3f},{pid},,")
        text = "\ufeff" + "\r\n".join(rows) + "\r\n"
        (folder / f"{pid}_ratings.csv").write_bytes(text.encode("utf-8"))
    (folder / "study.toml").write_text(STUDY_TOML)
    return folder / "study.toml"
