"""Convert Psychtoolbox's demo calibration file into the readings fixtures beside this script.

Run once by hand (not by the tests); the input is ``PTB3TestCal.mat`` from Debian's
``psychtoolbox-3-common`` package (``/usr/share/psychtoolbox-3/PsychCalDemoData``), and the
CIE 1931 luminous efficiency from the same package
(``PsychColorimetricData/PsychColorimetricMatFiles/T_xyz1931.mat``)::

    python tests/data/calibration/convert_ptb_cal.py PTB3TestCal.mat T_xyz1931.mat

Each gun was measured alone at each drive level (a spectrum per level, ambient subtracted).
Luminance of a gun = 683 lm/W x sum over wavelength bands of ybar(lambda) x spectral radiance
per band; a grey ramp's luminance = the ambient + the sum of the three guns (the additivity the
toolbox's own linear model assumes). The toolbox's fitted table (``gammaTable``, normalised per
gun) becomes luminance the same way: ambient + sum over guns of (gun white) x table.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import scipy.io as sio

from calibration.readings import READINGS_COLUMNS

HERE = Path(__file__).parent
#: (index in the file's cals array, fixture folder, calibration id, ISO date of the file's date)
DISPLAYS = [
    (0, "ptb_apple17_crt_2000", "ptb-apple17-crt-2000", "2000-08-21T11:17:50Z"),
    (5, "ptb_monitor_a_2006", "ptb-monitor-a-2006", "2006-11-13T13:55:05Z"),
]


def _luminance(spectra: np.ndarray, s_band: np.ndarray, t_path: Path) -> np.ndarray:
    t = sio.loadmat(t_path, squeeze_me=True)
    s0 = t["S_xyz1931"]
    wl_t = s0[0] + s0[1] * np.arange(s0[2])
    wl = s_band[0] + s_band[1] * np.arange(s_band[2])
    ybar = np.interp(wl, wl_t, t["T_xyz1931"][1])
    return 683.0 * ybar @ spectra


def main(mat_path: str, t_path: str) -> None:
    cals = sio.loadmat(mat_path, squeeze_me=True, struct_as_record=False)["cals"]
    for index, folder, cal_id, date in DISPLAYS:
        c = cals[index]
        s_band = np.asarray(c.S_device, int)
        nw = int(s_band[2])
        mon = np.asarray(c.rawdata.mon, float)
        n = mon.shape[0] // nw
        guns = np.array([[_luminance(mon[j * nw:(j + 1) * nw, g], s_band, Path(t_path))
                          for g in range(3)] for j in range(n)])
        ambient = float(_luminance(np.asarray(c.P_ambient, float).ravel(), s_band, Path(t_path)))
        drive = np.asarray(c.rawdata.rawGammaInput, float).ravel()
        drive = drive / 255.0 if drive.max() > 1 else drive
        out = HERE / folder
        out.mkdir(exist_ok=True)
        with open(out / "readings.csv", "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(READINGS_COLUMNS)
            if ambient > 0:
                w.writerow([cal_id, date, "pr650", 0, 0, 0.0, 0, f"{ambient:.6g}",
                            "ambient (all guns at 0)"])
            for lv, g in zip(drive, guns):
                w.writerow([cal_id, date, "pr650", 0, 0, f"{lv:.6g}", 0,
                            f"{ambient + g.sum():.6g}",
                            f"R={g[0]:.6g};G={g[1]:.6g};B={g[2]:.6g};ambient={ambient:.6g}"])
        table_in = np.asarray(c.gammaInput, float).ravel()
        table_in = table_in / table_in.max()
        table = np.asarray(c.gammaTable, float)[:, :3]
        lum = ambient + table @ guns[-1]
        with open(out / "toolbox_table.csv", "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["level", "luminance_cd_m2"])
            for lv, y in zip(table_in, lum):
                w.writerow([f"{lv:.6g}", f"{y:.6g}"])


if __name__ == "__main__":
    main(*sys.argv[1:3])
