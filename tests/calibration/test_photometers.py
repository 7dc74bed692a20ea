"""The real drivers against the simulated instrument over a pseudo-terminal, faults injected."""

from __future__ import annotations

import pytest

from calibration import (
    BadReading,
    CalibrationError,
    PhotometerError,
    PhotometerNotFound,
    PhotometerTimeout,
    SimulatedCRT,
)
from calibration.photometers import open_photometer

DEVICES = ["pr655", "pr650", "ls100"]
NOISELESS = SimulatedCRT(noise_rel=0.0, noise_abs=0.0)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("drive", [0.0, 0.5, 1.0])
def test_reading_is_the_simulated_luminance(fake_photometer, device, drive):
    fake = fake_photometer(device, drive=drive, crt=NOISELESS)
    with open_photometer(device, fake.port, timeout_s=1.0) as phot:
        reading = phot.measure()
    want = float(NOISELESS.luminance(drive))
    # Replies carry 4 significant digits.
    assert reading.luminance_cd_m2 == pytest.approx(want, rel=1e-3)
    assert reading.raw_reply


@pytest.mark.parametrize("device", DEVICES)
def test_timeout_is_retried(fake_photometer, device):
    fake = fake_photometer(device, faults=["timeout:1"])
    with open_photometer(device, fake.port, timeout_s=0.3, retries=2) as phot:
        assert phot.measure().luminance_cd_m2 > 50
    assert fake.n_measurements == 2  # the timed-out one and the retry


@pytest.mark.parametrize("device", DEVICES)
def test_persistent_timeout_quotes_last_reply(fake_photometer, device):
    fake = fake_photometer(device, faults=["timeout:all"])
    with (open_photometer(device, fake.port, timeout_s=0.2, retries=2) as phot,
          pytest.raises(PhotometerTimeout, match="after 3 attempt") as info):
        phot.measure()
    assert info.value.last_reply  # half a reply line arrived before the silence
    assert repr(info.value.last_reply) in str(info.value)
    assert fake.n_measurements == 3


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("kind", ["garbled", "out_of_range", "saturated"])
def test_bad_replies_are_flagged(fake_photometer, device, kind):
    fake = fake_photometer(device, faults=[f"{kind}:2"])
    with open_photometer(device, fake.port, timeout_s=1.0) as phot:
        good = phot.measure()
        with pytest.raises(BadReading) as info:
            phot.measure()
        assert info.value.kind == kind
        assert info.value.raw_reply and info.value.raw_reply != good.raw_reply
        assert phot.measure().luminance_cd_m2 == pytest.approx(good.luminance_cd_m2, rel=0.05)


@pytest.mark.parametrize("device", DEVICES)
def test_unplug_raises_photometer_error(fake_photometer, device):
    fake = fake_photometer(device, faults=["unplug:2"])
    with open_photometer(device, fake.port, timeout_s=0.5) as phot:
        phot.measure()
        with pytest.raises(PhotometerError, match="rerun"):
            phot.measure()


@pytest.mark.parametrize("device", DEVICES)
def test_wrong_port_lists_available_ports(tmp_path, device):
    with pytest.raises(PhotometerNotFound, match="serial ports found: ") as info:
        open_photometer(device, str(tmp_path / "ttyUSB9"))
    assert "ttyUSB9" in str(info.value)


def test_pr650_driver_on_an_ls100_line_is_not_found(fake_photometer):
    fake = fake_photometer("ls100")
    with pytest.raises(PhotometerNotFound, match="pr650"):
        # The LS-100 answers b1 with ER00 at the wrong line settings: garbage, not '000'.
        open_photometer("pr650", fake.port, timeout_s=0.3)


def test_unknown_device_is_rejected():
    with pytest.raises(CalibrationError, match="unknown"):
        open_photometer("spectrascan", "/dev/null")


def test_ls100_line_settings_reach_the_pty(fake_photometer):
    fake = fake_photometer("ls100")
    with open_photometer("ls100", fake.port, timeout_s=1.0) as phot:
        phot.measure()
        # The pty refused CS7/PARENB; the tolerant port recorded what the driver asked for.
        assert phot._drv.com.requested_line == "4800 7E2"
        assert phot.info()["serial"] == "4800 7E2"


def test_psychopy_pr655_driver_works_unchanged(fake_photometer):
    from psychopy_photoresearch.pr import PR655

    fake = fake_photometer("pr655", crt=NOISELESS)
    drv = PR655(fake.port)
    assert drv.type == "PR-655"
    drv.measure()
    assert drv.lastLum == pytest.approx(float(NOISELESS.luminance(1.0)), rel=1e-3)
    assert len(drv.lastSpectrum[0]) > 90
    drv.com.close()


def test_psychopy_pr650_driver_crashes_on_time_clock(fake_photometer):
    # Why calibration/photometers/pr650.py exists: the plugin's measure() calls time.clock.
    from psychopy_photoresearch.pr import PR650

    fake = fake_photometer("pr650")
    drv = PR650(fake.port)
    assert drv.OK
    with pytest.raises(AttributeError, match="clock"):
        drv.measure()
    drv.com.close()
