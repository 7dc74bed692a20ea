"""The simulated CRT: each effect does what its parameter says."""

from __future__ import annotations

import numpy as np
import pytest

from calibration import CalibrationError, SimulatedCRT, gamma_luminance, load_crt


def test_shipped_crt_toml_loads():
    crt = load_crt()
    assert crt == SimulatedCRT()  # the TOML documents the defaults


def test_noiseless_centre_is_the_extended_power_function():
    crt = SimulatedCRT(bits=16)
    x = np.linspace(0, 1, 33)
    want = gamma_luminance(x, model="extended_power", params=crt.true_gamma_params())
    assert crt.luminance(x) == pytest.approx(want, rel=1e-3, abs=1e-3)


def test_black_level_adds_ambient():
    crt = SimulatedCRT(black_cd_m2=0.2, ambient_cd_m2=0.7)
    assert crt.luminance(0.0) == pytest.approx(0.9)


def test_quantisation_to_eight_bits():
    crt = SimulatedCRT(cutoff=0)
    # Two drives inside one 8-bit step give the same luminance; a full step apart they differ.
    assert crt.luminance(100.2 / 255) == crt.luminance(99.8 / 255)
    assert crt.luminance(101 / 255) > crt.luminance(100 / 255)


def test_corners_are_dimmer_and_warm_up_drifts():
    crt = SimulatedCRT(falloff=0.2, tilt_x=0.0, warmup_drift=0.1, warmup_tau_s=100)
    above = crt.luminance(1.0, 1, 1) - crt.black_total_cd_m2
    assert above / (crt.luminance(1.0) - crt.black_total_cd_m2) == pytest.approx(0.8)
    cold = crt.luminance(1.0, t_s=0.0) - crt.black_total_cd_m2
    assert cold == pytest.approx(0.9 * crt.white_cd_m2)
    assert crt.luminance(1.0, t_s=100.0) < crt.luminance(1.0, t_s=500.0)


def test_noise_has_the_set_spread(rng):
    crt = SimulatedCRT(noise_rel=0.01, noise_abs=0.0)
    lum = crt.luminance(np.ones(4000), rng=rng)
    assert np.std(lum) / np.mean(lum) == pytest.approx(0.01, rel=0.1)


@pytest.mark.parametrize("kw", [{"gamma": 0.1}, {"cutoff": 0.7}, {"bits": 0}, {"falloff": 1.5}])
def test_invalid_parameters_are_rejected(kw):
    with pytest.raises(CalibrationError, match="simulated CRT"):
        SimulatedCRT(**kw)


def test_unknown_toml_key_is_named(tmp_path):
    path = tmp_path / "crt.toml"
    path.write_text("[crt]\ngama = 2.2\n")
    with pytest.raises(CalibrationError, match=r"unknown parameter\(s\) \['gama'\]"):
        load_crt(path)


def test_drive_outside_range_is_rejected():
    with pytest.raises(CalibrationError, match=r"drive must lie in \[0, 1\]"):
        SimulatedCRT().luminance(1.2)


@pytest.mark.parametrize("reader", ["crt", "display"])
def test_a_missing_or_broken_display_file_is_named_with_the_fix(tmp_path, reader):
    from calibration.run import load_display_file

    read = load_crt if reader == "crt" else load_display_file
    with pytest.raises(CalibrationError, match=r"display file .*nothere\.toml not found"):
        read(tmp_path / "nothere.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[crt\ngamma = 2.2\n")
    with pytest.raises(CalibrationError, match=r"broken\.toml is not valid TOML"):
        read(broken)
    empty = tmp_path / "empty.toml"
    empty.write_text("[other]\nx = 1\n")
    with pytest.raises(CalibrationError, match=rf"has no \[{reader}\] table"):
        read(empty)
