"""Write the CSV excerpts of the paper-on-paper spring-slider logs from the original MATLAB files.

Source: https://github.com/npusteln/stickslip (N. Pustelnik, V. Vidal, ENS de Lyon; CeCILL-B),
``data_raw/k1002Nm_v42.mat`` and ``data_raw/k168Nm_v42.mat`` (variables ``t`` [s] and ``Fnorm``,
the spring force over the slider's weight m g, m = 30.7 g, g = 9.81 m/s^2, as in the repository's
``ex1.m``), published with J. Colas, N. Pustelnik, C. Oliver, P. Abry, J.-C. Geminard, V. Vidal,
"Nonlinear denoising for solid friction dynamics characterization", Phys. Rev. E 100, 032803 (2019).

Usage: python tests/data/paper_slider/make_excerpt.py DIR_WITH_MAT_FILES [--force]

The first ``SECONDS`` of each record, every sample (2 kHz), the force converted to mN (the rig files
write the slider on a 1 m lever, so N is N m), the drive's speed (42 um/s) as a column.  Nothing is
filtered: the impulsive noise of the original is kept.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.io import loadmat

M, G, V = 30.7e-3, 9.81, 42e-6
SECONDS = {"k1002Nm_v42": 8.0, "k168Nm_v42": 16.0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", help="folder holding k1002Nm_v42.mat and k168Nm_v42.mat")
    ap.add_argument("--force", action="store_true", help="overwrite the CSV files")
    a = ap.parse_args(argv)
    here = Path(__file__).resolve().parent
    for name, seconds in SECONDS.items():
        d = loadmat(Path(a.source) / f"{name}.mat")
        t, f = d["t"].ravel(), d["Fnorm"].ravel()
        n = int(round(seconds * 2000)) + 1
        out = here / f"{name}.csv"
        if out.exists() and not a.force:
            raise SystemExit(f"{out} exists (use --force)")
        rows = [f"# paper-on-paper spring-slider, {name}: the first {seconds:g} s of data_raw/{name}.mat of "
                f"https://github.com/npusteln/stickslip (CeCILL-B; Colas et al., Phys. Rev. E 100, 032803, 2019); "
                f"see README.md here",
                "t [s],torque_spring [mN m],v_drive [rad/s]"]
        rows += [f"{tt - t[0]:.4f},{1e3 * ff * M * G:.5g},{V:g}" for tt, ff in zip(t[:n], f[:n])]
        out.write_text("\n".join(rows) + "\n")
        print(f"wrote {out} ({n} rows)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
