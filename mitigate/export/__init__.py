"""The controller leaves the workbench: a C library (and an FMU) of a scenario's controller with its
estimator, the same C the workbench runs.

:func:`export_controller` writes, for one ``[[controllers]]`` entry of a scenario and the
scenario's estimator, a self-contained folder::

    include/<prefix>.h      the API: create(params) / step(t, in, out) / reset / destroy, the layout
                            of in[], out[] and params[] with names and units
    src/                    the C cores (the workbench's own: ss_nmpc.c or ss_laws.c, ss_ekf.c and
                            with an MHE ss_mhe.c, ss_common.c), the CasADi-generated functions, the
                            glue with the exported defaults
    vendor/                 hpipm and blasfeo as the casadi wheel ships them, for the NMPC
                            (mitigate.export.files)
    test/replay.c           the workbench's logged run through the library, checked to 1e-9, with
                            allocations after create counted; test/reference.csv its data
    CMakeLists.txt, Makefile, README.md (the API), export.json (what was exported, from what)
    rt/driver.c             the real-time driver example against the workbench's plant over UDP
                            (mitigate.export.driver, mitigate.export.plant_server)
    <prefix>.fmu            with ``fmu=True``: an FMI 2.0 co-simulation FMU (mitigate.export.fmu)

Every kind exports through the same glue (:mod:`mitigate.export.glue`): the NMPC with any input set
(:mod:`mitigate.export.nmpc`), SoftSpeed, Z-Torque, D-OSKIL and the brake
(:mod:`mitigate.export.laws`) each describe their commands, channels, runtime parameters and a small
C adapter.  The estimator is the scenario's: the EKF, or the MHE with its EKF alongside.  The
workbench's controllers and estimators run these very cores (the NMPC's and the laws'
``implementation = "c"``, the EKF's and the MHE's ``compile = true``), so the exported controller
and the benchmarked one cannot drift; the reference run checks it.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from models.cbuild import CSRC, generate, read_source
from models.errors import ConfigError
from models.status import Status
from mitigate.export.files import BUILD_TYPES, check_build_type
from mitigate.export.interface import Interface, c_name

__all__ = ["export_controller", "ExportResult", "EXPORTABLE", "FAST_QP", "build_export"]

#: controller kinds that export (the NMPC with any input set; the industry's laws and the brake)
EXPORTABLE = ("nmpc", "softspeed", "ztorque", "doskil", "brake")


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_controller` wrote.

    Attributes
    ----------
    status : Status.OK; message : one line; out : the folder; prefix : the C names' prefix
    files : every file written (relative to ``out``); interface : the layout of in[], out[], params[]
    reference_rows : DAQ periods in ``test/reference.csv`` (0: none written)
    hints : one line each, what the export would gain from a setting it does not use (an NMPC on the
        structured QP: the condensed one with hpipm's "speed" preset, :data:`FAST_QP`)
    """

    status: Status
    message: str
    out: Path
    prefix: str
    files: tuple[str, ...]
    interface: Interface
    reference_rows: int
    hints: tuple[str, ...] = ()

    @property
    def success(self) -> bool:
        return self.status.success

    def as_dict(self) -> dict:
        return {"status": self.status.value, "message": self.message, "out": str(self.out), "prefix": self.prefix,
                "files": list(self.files), "reference_rows": self.reference_rows,
                "inputs": [[p.name, p.unit] for p in self.interface.inputs],
                "outputs": [[p.name, p.unit] for p in self.interface.outputs],
                "params": [[p.name, p.unit, p.value] for p in self.interface.params], "hints": list(self.hints)}


#: the NMPC's QP setting measured for export (the main scenario declares it; docs/export.md)
FAST_QP = {"qp_condensing": "partial", "qp_mode": "speed", "qp_mu0": 1e-4}


def _hints(kind: str, ctrl) -> tuple[str, ...]:
    """What the export would gain (:attr:`ExportResult.hints`)."""
    o = getattr(ctrl, "options", None)
    if kind != "nmpc" or getattr(o, "qp_condensing", None) != "none":
        return ()
    setting = ", ".join(f"{k} = {v!r}" if isinstance(v, str) else f"{k} = {v:g}" for k, v in FAST_QP.items())
    return (f"the NMPC solves the structured QP (qp_condensing = 'none', the options' default); with {setting} "
            f"in its table the feedback was 1.8-8 times shorter on the rigs measured (docs/export.md)",)


def _controller_index(scenario, name: str) -> int:
    names = [c.name for c in scenario.controllers]
    if name not in names:
        raise ConfigError(f"{scenario.where}: controller {name!r} is not in the scenario (it has: {', '.join(names)})")
    return names.index(name)


def _estimator(scenario):
    """The scenario's estimator, built as the closed loop builds it."""
    from estimators.base import EstimatorContext
    from estimators.online.factory import make_estimator
    u0 = scenario.programme(0.0)
    x0 = scenario.model.steady_sliding(u0, scenario.model_params) if scenario.sim.start == "sliding" \
        else np.zeros(scenario.model.nx)
    return make_estimator(scenario.estimator, EstimatorContext(
        scenario.model, scenario.model_params, scenario.dt, scenario.sensors, x0, f"{scenario.where}: estimator", None))


def export_controller(scenario, controller: str, out, *, reference: float | None = 60.0, prefix: str | None = None,
                      force: bool = False, fmu: bool = False, build_type: str = "Release") -> ExportResult:
    """Write the C library of ``controller`` (a ``[[controllers]]`` name) with the scenario's estimator.

    Parameters
    ----------
    scenario : a :class:`mitigate.scenario.Scenario` or the path of a scenario file
    controller : the controller's name in the scenario
    out : the folder to write (refused if it exists, unless ``force``)
    reference : seconds of the scenario to run in the workbench and write as ``test/reference.csv``
        (the replay test's data; None or 0: none)
    prefix : the C names' prefix (default: from the controller's name)
    fmu : also build ``<prefix>.fmu``, an FMI 2.0 co-simulation FMU of the library
        (:func:`mitigate.export.fmu.write_fmu`; needs a C compiler and cmake)
    build_type : the FMU's build, ``"Release"`` (-O2, as measured) or ``"Debug"`` (-O0 -g, builds
        about 4x faster, the same results); see :func:`build_export`

    Raises
    ------
    ConfigError : an unknown controller, a kind that does not export, an estimator other than the
        EKF or the MHE (with ``qpsol = "ldl"``), ``out`` that exists; ``fmu`` without a C compiler and cmake; nothing is written then.
    RuntimeError : ``fmu`` and the FMU's build failed; nothing is written then.
    """
    from estimators.online.compiled import EKF_CONFIG, EKF_SOURCES, MHE_CONFIG
    from mitigate.controllers.factory import context_for, make_controller
    from mitigate.export.driver import write_driver
    from mitigate.export.files import cmake_lists, makefile, readme, replay_program, vendor_hpipm
    from mitigate.export.fmu import fmu_tools, write_fmu
    from mitigate.export.glue import estimator_functions, estimator_sources, glue_source, is_mhe
    from mitigate.scenario import Scenario, load_scenario

    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    i = _controller_index(sc, controller)
    spec = sc.controllers[i]
    if spec.kind not in EXPORTABLE:
        raise ConfigError(f"{sc.where}: controller {controller!r} is of kind {spec.kind!r}; export supports "
                          f"{', '.join(EXPORTABLE)}")
    est_kind = (sc.estimator or {}).get("kind", "ekf")
    if est_kind not in ("ekf", "mhe"):
        raise ConfigError(f"{sc.where}: estimator.kind = {est_kind!r}; export supports the EKF and the MHE")
    check_build_type(build_type)
    if fmu:
        fmu_tools()
    out = Path(out)
    if out.exists() and not force:
        raise ConfigError(f"export: --out {out} exists; refusing to overwrite (use --force or another folder)")
    prefix = prefix or c_name(controller).lower()
    if not prefix.isidentifier():
        raise ConfigError(f"export: prefix must be a C identifier, got {prefix!r}")
    ctx = context_for(sc, i)
    ctrl = make_controller(spec, ctx)
    if getattr(ctrl, "compiled", None) is None:
        raise ConfigError(f"{sc.where}: controller {controller!r} does not run the compiled step (it needs "
                          + ("solver = 'rti' or 'sqp', qp_solver = 'hpipm', compile = true, implementation = 'c')"
                             if spec.kind == "nmpc" else "implementation = 'c' and a C compiler)"))
    ekf = _estimator(sc)
    if not getattr(ekf, "compiled", False) or (est_kind == "mhe" and not is_mhe(ekf)):
        raise ConfigError(f"{sc.where}: the {est_kind.upper()} did not compile its update "
                          f"({getattr(ekf, 'compile_status', '')}); export needs a C compiler"
                          + (" and qpsol = 'ldl'" if est_kind == "mhe" else ""))
    if list(ekf.em.p) != list(ctx.params.vector()):
        raise ConfigError("export: the estimator's and the controller's rig parameters differ; export needs one set")
    kind = _kind(spec.kind)(ctrl, ekf)
    funs = f"{prefix}_gen"
    gen_src, gen_hdr = generate(list(kind.functions) + list(estimator_functions(ekf)), funs)
    glue, hdr, itf = glue_source(prefix, kind, sc.model, ctx.params, ekf, sc.control.every, sc.sim.start != "sliding",
                                 funs)
    src = read_source("ss_common.h", "ss_common.c", folder=CSRC)
    src.update(kind.sources)
    src.update(read_source(*estimator_sources(ekf), folder=EKF_SOURCES))
    src["ss_ekf_config.h"] = EKF_CONFIG.header()
    if is_mhe(ekf):
        src["ss_mhe_config.h"] = MHE_CONFIG.header()
    src[f"{funs}.c"], src[f"{funs}_funs.h"] = gen_src, gen_hdr
    src[f"{prefix}.c"] = glue
    sources = sorted(n for n in src if n.endswith(".c"))
    notes = list(kind.notes) + [
        (f"the MHE (window {ekf.N}, {ekf.options.max_iter} Gauss-Newton iteration(s) a sample) with its EKF alongside: "
         if is_mhe(ekf) else "the EKF: ")
        + f"its states ({', '.join(ekf.names)}), noise levels and prior, from the rig file and the scenario's sensors",
        f"the DAQ period {sc.dt:g} s; the controller runs every {sc.control.every} period(s)",
        "changing a rig parameter changes the estimator (and an NMPC's prediction), not the settings derived "
        "from it above: re-export for a rig that changed much"]
    rows = 0
    with tempfile.TemporaryDirectory(prefix=".export_", dir=str(out.parent if out.parent.exists() else Path("."))) as tmp:
        d = Path(tmp) / "x"
        (d / "src").mkdir(parents=True)
        (d / "include").mkdir()
        (d / "test").mkdir()
        files = []
        for name, text in src.items():
            (d / "src" / name).write_text(text)
            files.append(f"src/{name}")
        (d / "include" / f"{prefix}.h").write_text(hdr)
        files.append(f"include/{prefix}.h")
        if kind.qp:
            files += [f"vendor/{f}" for f in vendor_hpipm(d / "vendor")]
        (d / "CMakeLists.txt").write_text(cmake_lists(prefix, sources, qp=kind.qp))
        (d / "Makefile").write_text(makefile(prefix, sources, qp=kind.qp))
        (d / "test" / "replay.c").write_text(replay_program(prefix, itf))
        (d / "README.md").write_text(readme(prefix, itf, kind.what, sc.where, notes, qp=kind.qp))
        files += ["CMakeLists.txt", "Makefile", "test/replay.c", "README.md"]
        files += write_driver(d, prefix, itf, sc.dt)
        if reference:
            rows = _write_reference(sc, i, itf, float(reference), d / "test" / "reference.csv")
            files.append("test/reference.csv")
        manifest = {"scenario": sc.where, "controller": controller, "kind": spec.kind, "prefix": prefix,
                    "rig": sc.model.name, "dt": sc.dt, "every": sc.control.every,
                    "inputs": [p.name for p in itf.inputs], "outputs": [p.name for p in itf.outputs],
                    "params": {p.name: p.value for p in itf.params}}
        (d / "export.json").write_text(json.dumps(manifest, indent=2) + "\n")
        files.append("export.json")
        if fmu:
            files.append(write_fmu(d, prefix, itf, sc, title=kind.what, notes=notes, build_type=build_type))
        if out.exists():
            shutil.rmtree(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        os.replace(d, out)
    return ExportResult(Status.OK, f"exported {controller!r} as {prefix} ({len(itf.inputs)} inputs, "
                                   f"{len(itf.outputs)} outputs, {len(itf.params)} parameters) to {out}",
                        out, prefix, tuple(files), itf, rows, _hints(spec.kind, ctrl))


def _kind(kind: str):
    """The function describing an exportable kind (:class:`mitigate.export.glue.KindExport`)."""
    if kind == "nmpc":
        from mitigate.export.nmpc import nmpc_export
        return nmpc_export
    from mitigate.export.laws import law_export
    return law_export


def _write_reference(sc, index: int, itf: Interface, seconds: float, path: Path) -> int:
    """Run the scenario's controller in the workbench for ``seconds`` and write what a real-time loop
    would have given the library (in[]) and what the workbench did (out[])."""
    from mitigate.closedloop import run_closed_loop
    from mitigate.controllers.factory import context_for, make_controller
    dur = min(sc.duration, max(seconds, sc.dt))
    # the library runs at the DAQ rate with no deadline of its own: the real-time loop monitors deadlines
    sc2 = replace(sc, duration=dur, control=sc.control.replace(deadline=None, latency=0.0))
    ctrl = make_controller(sc2.controllers[index], context_for(sc2, index))
    res = run_closed_loop(sc2, ctrl, estimator=_estimator(sc2))
    n = len(res.t)
    k_start = int(math.ceil(sc2.control.start / sc2.dt - 1e-9))
    cols = []
    for p in itf.inputs:
        if p.name.startswith("programme:"):
            j = sc2.model.inputs.index(p.name.partition(":")[2])
            cols.append(np.array([sc2.programme(t)[j] for t in res.t]))
        elif p.name == "target_speed":
            cols.append(np.array([float(sc2.control.speed(t)) if sc2.control.speed is not None
                                  else sc2.model.nominal_speed() for t in res.t]))
        elif p.name == "enable":
            cols.append((np.arange(n) >= k_start).astype(float))
        else:
            cols.append(np.asarray(res.y.get(p.name, np.full(n, np.nan)), float))
    for p in itf.outputs:
        if p.name.startswith("estimate:"):
            cols.append(res.xhat[:, list(res.xhat_names).index(p.name.partition(":")[2])])
        else:
            cols.append(np.asarray(res.commands[p.name], float))
    data = np.column_stack([res.t] + cols)
    header = ",".join(["t"] + [p.name for p in itf.inputs] + [p.name for p in itf.outputs])
    np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.17g")
    return n


def build_export(out, *, tool: str = "cmake", build_type: str = "Release") -> Path:
    """Build an exported folder with CMake (or make) and return the shared library's path.

    Parameters
    ----------
    out : the exported folder (:func:`export_controller`)
    tool : ``"cmake"`` (into ``out/build``) or ``"make"`` (in ``out``)
    build_type : ``"Release"`` (-O2: the build whose times BENCHMARKS.md gives) or ``"Debug"``
        (-O0 -g: the generated C compiles about 4x faster; the results are the same, since neither
        build uses fast-math or fused multiply-adds)

    Raises
    ------
    ConfigError : no C compiler or no cmake/make on this machine (one line naming what to install).
    RuntimeError : the build failed (the tool's last lines).
    """
    out = Path(out)
    check_build_type(build_type)
    exe = shutil.which(tool)
    if exe is None or (shutil.which("cc") or shutil.which("gcc")) is None:
        raise ConfigError(f"building an export needs a C compiler and {tool} (install them with the package manager)")
    prefix = json.loads((out / "export.json").read_text())["prefix"]
    if tool == "cmake":
        b = out / "build"
        for cmd in ([exe, "-S", str(out), "-B", str(b), f"-DCMAKE_BUILD_TYPE={build_type}"], [exe, "--build", str(b)]):
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode:
                raise RuntimeError(f"{' '.join(cmd[:2])} failed: {(r.stdout + r.stderr)[-800:]}")
        return b / f"lib{prefix}.so"
    r = subprocess.run([exe, "-C", str(out), f"OPT={BUILD_TYPES[build_type]}"], capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"make failed: {(r.stdout + r.stderr)[-800:]}")
    return out / f"lib{prefix}.so"
