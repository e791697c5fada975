"""``python -m mitigate.export.rt``: the workbench's plant served to an exported controller's real-time
driver over UDP (:mod:`mitigate.export.plant_server`), or both in one command with ``--run``
(:func:`mitigate.export.driver.run_realtime`).

Examples::

    python -m mitigate.export.rt scenarios/stick_slip_30rpm.toml out/nmpc_c --run 30
    python -m mitigate.export.rt scenarios/stick_slip_30rpm.toml out/nmpc_c --port 47100 &   # then the driver
"""

from __future__ import annotations

import argparse
import json
import sys

from mitigate.export.driver import run_realtime
from mitigate.export.plant_server import PlantServer
from models.errors import ConfigError

__all__ = ["main"]


def main(argv=None) -> int:
    """``python -m mitigate.export.rt`` (module docstring); exit 0, 1 a failed run, 2 bad input."""
    ap = argparse.ArgumentParser(prog="python -m mitigate.export.rt", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenario", metavar="SCENARIO.toml", help="the scenario the folder was exported from")
    ap.add_argument("export", metavar="DIR", help="the folder `mitigate export` wrote")
    ap.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    ap.add_argument("--port", type=int, default=None,
                    help="UDP port (default 47100, with --run any free port; 0: any free port)")
    ap.add_argument("--log", metavar="CSV", help="write the run (t, in[], commands, true speed) here")
    ap.add_argument("--run", type=float, metavar="SECONDS",
                    help="also start the folder's driver (build/<prefix>_rt) for SECONDS of samples and print both reports")
    ap.add_argument("--priority", type=int, default=0, help="with --run: the driver's SCHED_FIFO priority (0: normal)")
    ap.add_argument("--driver-log", metavar="CSV", help="with --run: the driver's per-period log (times in us)")
    args = ap.parse_args(argv)
    try:
        if args.run is not None:
            res = run_realtime(args.scenario, args.export, args.run, port=args.port or 0, priority=args.priority,
                               log=args.log, driver_log=args.driver_log)
            print(res.text())
            return 0 if res.success else 1
        server = PlantServer(args.scenario, args.export, host=args.host, port=47100 if args.port is None else args.port)
        print(f"plant server: {server.scenario.where} on {server.host}:{server.port}; waiting for the driver",
              flush=True)
        report = server.serve()
        if args.log:
            server.write_log(args.log, report)
        server.close()
        print(json.dumps(report.summary()), flush=True)
        return 0 if report.success else 1
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
