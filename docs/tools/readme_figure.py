"""The README's figure: the objective disc's speed under PI only and under the NMPC (the main job).

Reads the logs ``mitigate run`` wrote (``log_pi_only.csv``, ``log_nmpc.csv``) with the project's
own CSV reader and draws the true speed of rig3's objective body R1 against the programme::

    mitigate run scenarios/stick_slip_30rpm.toml --out /tmp/main
    python docs/tools/readme_figure.py /tmp/main docs/img/main_job.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from mitigate.scenario import load_scenario  # noqa: E402
from models import read_csv  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "scenarios" / "stick_slip_30rpm.toml"
RUNS = (("log_pi_only.csv", "PI only (the drive's own speed loop)", "tab:red"),
        ("log_nmpc.csv", "NMPC with the EKF", "tab:blue"))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="Example: python docs/tools/readme_figure.py /tmp/main docs/img/main_job.png")
    p.add_argument("run_dir", type=Path, help="an output folder of `mitigate run scenarios/stick_slip_30rpm.toml`")
    p.add_argument("png", type=Path, help="the figure to write")
    args = p.parse_args(argv)
    sc = load_scenario(SCENARIO)
    body = sc.model.objective_body
    fig, ax = plt.subplots(figsize=(8.0, 3.2), dpi=110)
    logs = [read_csv(args.run_dir / name) for name, _, _ in RUNS]
    for log, (_, label, colour) in zip(logs, RUNS):
        ax.plot(log.t, log[f"true_omega_{body}"], color=colour, lw=0.9, label=label)
    # PI only sends the programme itself; the NMPC's log holds its own set-point
    ax.plot(logs[0].t, logs[0]["omega_ref"], color="k", lw=0.8, ls="--", label="programme (30 rpm)")
    ax.axvline(sc.control.start, color="0.5", lw=0.8)
    ax.annotate("control on", (sc.control.start, 0.0), xytext=(4, 2), textcoords="offset points",
                color="0.3", fontsize=8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"speed of disc {body} [rad/s]")
    ax.set_title("rig3, stick-slip at 30 rpm, N1 = 20 N: `mitigate run scenarios/stick_slip_30rpm.toml`", fontsize=9)
    ax.legend(loc="upper left", fontsize=8, ncol=3, frameon=False, bbox_to_anchor=(0.0, -0.22))
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(args.png)
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
