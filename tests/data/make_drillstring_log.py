"""Write tests/data/drillstring_stickslip.csv: a synthetic 3 s, 1 kHz stick-slip log of the
drill-string rig (models/rigs/drillstring.toml), made by our plant (models.plant.simulate).

Truth (the rig file's values except): k = 16.5 N m/rad, d = 0.03 N m s/rad, mu_sb = 0.75,
mu_cb = 0.45 (the fit starts from the rig file's 15, 0.035, 0.8, 0.5 or from a guess).
Top speed: 3 rad/s from rest; true weight on bit 200 N + 10 N sin(2 pi 0.7 t); the load cell
adds its 4 N noise, the encoders count 10000 (bit) and 50000 (top) per turn; seed 7.

Run from the repository root:  PYTHONPATH=. python tests/data/make_drillstring_log.py [--force]
"""

import sys
from pathlib import Path

import numpy as np

from models import get_model
from models.files import atomic_write_text
from models.plant import SimOptions, simulate

TRUE = {"k": 16.5, "d": 0.03, "mu_sb": 0.75, "mu_cb": 0.45}
DT, DURATION, SEED = 0.001, 3.0, 7
OUT = Path(__file__).with_name("drillstring_stickslip.csv")


def truth():
    return get_model("drillstring").published().replace(**TRUE)


def make() -> str:
    m = get_model("drillstring")
    n = int(round(DURATION / DT))
    t = np.arange(n) * DT
    U = np.column_stack([np.full(n, 3.0), 200.0 + 10.0 * np.sin(2 * np.pi * 0.7 * t)])
    sim = simulate(m, truth(), U, DURATION, SimOptions(dt=DT, nsub=4, seed=SEED))
    head = ("# synthetic drill-string stick-slip log: tests/data/make_drillstring_log.py (models.plant.simulate, "
            "seed 7)\n# truth: k = 16.5 N m/rad, d = 0.03 N m s/rad, mu_sb = 0.75, mu_cb = 0.45, other values from "
            "models/rigs/drillstring.toml; top speed 3 rad/s, WOB 200 N + 10 N sin(2 pi 0.7 t) + 4 N load-cell noise\n")
    return head + sim.to_log().to_csv_text(precision=8)


if __name__ == "__main__":
    atomic_write_text(OUT, make(), overwrite="--force" in sys.argv)
    print(f"wrote {OUT}")
