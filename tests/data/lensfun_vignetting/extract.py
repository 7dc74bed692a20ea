"""Extract the fixture profiles.csv from the lensfun lens database as Debian packages it.

    apt-get download liblensfun-data-v1 && dpkg-deb -x liblensfun-data-v1_*.deb x
    python extract.py x/usr/share/lensfun/version_1 > profiles.csv

Every distinct vignetting calibration of lensfun's 'pa' model (V = 1 + k1 r^2 + k2 r^4 +
k3 r^6, r: distance from the optical centre over the half diagonal) with its lens, focal length
(mm), aperture (f-number) and focus distance (m); 300 of them drawn at random (seed 0)."""
import csv
import glob
import sys
import xml.etree.ElementTree as ET

import numpy as np

rows, seen = [], set()
for path in sorted(glob.glob(f"{sys.argv[1]}/*.xml")):
    for lens in ET.parse(path).getroot().iter("lens"):
        model = lens.findtext("model") or ""
        maker = lens.findtext("maker") or ""
        for v in lens.iter("vignetting"):
            if v.get("model") != "pa":
                continue
            k = tuple(float(v.get(n)) for n in ("k1", "k2", "k3"))
            if k in seen:
                continue
            seen.add(k)
            rows.append([maker, model, v.get("focal"), v.get("aperture"), v.get("distance"), *k])
pick = np.random.default_rng(0).choice(len(rows), 300, replace=False)
out = csv.writer(sys.stdout, lineterminator="\n")
out.writerow(["maker", "model", "focal_mm", "aperture_f", "distance_m", "k1", "k2", "k3"])
for i in sorted(pick):
    out.writerow(rows[i])
print(f"{len(rows)} distinct profiles, 300 written", file=sys.stderr)
