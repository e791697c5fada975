"""``mitigate export``: a scenario's controller with its estimator as a C library for the rig."""

from __future__ import annotations

from mitigate.cliutil import add_command, emit_json, quantity
from mitigate.export.files import BUILD_TYPES
from models.errors import ConfigError

EPILOG = """\
Writes DIR: include/<name>.h (create / step / reset / destroy; the layout of in[], out[] and the
runtime parameters with their units), src/ (plain C: the workbench's own cores -- the NMPC's or the
law's (softspeed, ztorque, doskil, brake) -- and the scenario's estimator's (the EKF's, or the MHE's
with its EKF alongside), the CasADi-generated rig functions, the
exported defaults), vendor/ (the NMPC: hpipm and blasfeo as the casadi wheel ships them, with their
BSD-2 licences), CMakeLists.txt and a Makefile, README.md (the API),
test/replay.c with test/reference.csv: the workbench's own run of the scenario, which the built
library must reproduce to 1e-9 without allocating after create.  Nothing is written if the
scenario or the controller is refused, or DIR exists (use --force).
Also rt/driver.c, a real-time driver example: the library at the DAQ period against the
workbench's plant in another process over UDP, with missed deadlines counted.
--build also builds DIR with CMake and runs its replay test (needs a C compiler and cmake).
--fmu also writes DIR/<name>.fmu, an FMI 2.0 co-simulation FMU of the same library (built here).
--build-type Debug builds unoptimised (-O0 -g; the generated C compiles about 4x faster, with the
same results): for trying things and tests; the default Release (-O2) is the build to run on a rig.
--rt SECONDS builds, then runs the driver for SECONDS of samples against the scenario's plant and
prints its deadline statistics and the plant's stick-slip severity (docs/export.md).
Exit codes: 0 written (and built, replayed, run), 1 the build, the replay or the real-time run
failed, 2 bad input.

Example:
  mitigate export scenarios/stick_slip_30rpm.toml --controller NMPC --out out/nmpc_c
  mitigate export scenarios/stick_slip_30rpm.toml --controller NMPC --out out/nmpc_c --build --json
  mitigate export scenarios/stick_slip_30rpm.toml --controller SoftSpeed --out out/softspeed_c --build
  mitigate export scenarios/stick_slip_30rpm.toml --controller NMPC --out out/nmpc_c --fmu --rt 30
"""


def register(sub) -> None:
    p = add_command(sub, "export", help="export a controller with its estimator as a C library",
                    description=__doc__, epilog=EPILOG)
    p.add_argument("scenario", metavar="SCENARIO.toml", help="scenario file")
    p.add_argument("--controller", required=True, metavar="NAME", help="the [[controllers]] name to export")
    p.add_argument("--out", required=True, metavar="DIR", help="the folder to write")
    p.add_argument("--reference", type=quantity("time", lo=0.0), default=60.0, metavar="TIME",
                   help="time of the scenario the workbench runs for the replay test, in s or with a unit "
                        "(\"2 min\"; default 60 s; 0: none)")
    p.add_argument("--prefix", default=None, metavar="NAME", help="prefix of the C names (default: from the controller)")
    p.add_argument("--build", action="store_true", help="build with CMake and run the replay test")
    p.add_argument("--fmu", action="store_true", help="also build DIR/<name>.fmu, an FMI 2.0 co-simulation FMU")
    p.add_argument("--build-type", choices=tuple(BUILD_TYPES), default="Release",
                   help="the C build of --build, --fmu and --rt: Release (-O2, default) or Debug (-O0 -g, faster to "
                        "build, the same results)")
    p.add_argument("--rt", type=quantity("time", lo=0.0), default=None, metavar="TIME",
                   help="build, then run the real-time driver against the scenario's plant for TIME of samples (s or "
                        "with a unit)")
    p.add_argument("--force", action="store_true", help="replace DIR if it exists")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON document on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    import subprocess
    import sys

    from mitigate.export import build_export, export_controller

    if args.rt is not None and not (args.rt > 0):
        raise ConfigError(f"--rt must be a number of seconds > 0, got {args.rt}")
    try:
        res = export_controller(args.scenario, args.controller, args.out, reference=args.reference or None,
                                prefix=args.prefix, force=args.force, fmu=args.fmu,
                                build_type=args.build_type)
    except RuntimeError as exc:          # the FMU's build
        print(f"export failed: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 1
    out = res.as_dict()
    code = 0
    if args.build or args.rt is not None:
        try:
            so = build_export(res.out, build_type=args.build_type)
            out["library"] = str(so)
            if res.reference_rows:
                exe = so.parent / f"{res.prefix}_replay"
                r = subprocess.run([str(exe), str(res.out / "test" / "reference.csv")], capture_output=True, text=True)
                out["replay"] = (r.stdout or r.stderr).strip()
                words = out["replay"].split()      # "rows 3001 mismatches 0 ...": the same as numbers
                try:
                    if r.returncode == 0 and len(words) % 2 == 0:
                        out["replay_values"] = {k: float(v) for k, v in zip(words[::2], words[1::2])}
                except ValueError:
                    pass
                code = 0 if r.returncode == 0 else 1
        except RuntimeError as exc:
            out["build_error"] = str(exc).splitlines()[0]
            code = 1
    if args.rt is not None and code == 0:
        from mitigate.export.driver import run_realtime
        rt = run_realtime(args.scenario, res.out, args.rt)
        out["rt"] = {"status": rt.status.value, "message": rt.message, "driver": rt.driver,
                     "plant": rt.plant.summary() if rt.plant is not None else None}
        out["rt_text"] = rt.text()
        code = 0 if rt.success else 1
    if args.json:
        emit_json(out)
    else:
        print(res.message)
        for h in res.hints:
            print(f"note: {h}")
        if args.fmu:
            print(f"FMU: {res.out / (res.prefix + '.fmu')}")
        if "library" in out:
            print(f"built {out['library']}")
        if "replay" in out:
            print(f"replay: {out['replay']}")
        if "build_error" in out:
            print(f"build failed: {out['build_error']}")
        if "rt_text" in out:
            print(out["rt_text"])
    return code
