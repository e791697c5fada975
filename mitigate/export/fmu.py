"""The exported controller as an FMI 2.0 co-simulation FMU (``mitigate export ... --fmu``).

:func:`write_fmu` packages an export folder's C library as ``<prefix>.fmu`` (a zip)::

    modelDescription.xml         fmiVersion 2.0, CoSimulation (modelIdentifier = the prefix); every
                                 in[] entry an input, every out[] entry an output (the commands as
                                 ``command:<input>``, the estimate as ``estimate:<state>``), the last
                                 solve time and the step's status as outputs, every runtime
                                 parameter a fixed parameter with the exported default; units with
                                 their SI base units
    sources/                     the library's C sources, ``fmu_fmi2.c`` (the FMI functions, the
                                 same file for every export: ``mitigate/export/csrc``), the FMI 2.0
                                 headers, ``fmu_config.h`` (this export's layout), CMakeLists.txt
    binaries/linux64/<id>.so     built here from sources/ with CMake, with hpipm and blasfeo beside
                                 it (RPATH $ORIGIN)
    documentation/               index.html (what it is, the stepping rule, another platform's
                                 build, the variables), the library's README.md, the licences

One fmi2DoStep runs the library's step once per DAQ period: a communication step of ``n`` DAQ
periods runs ``n`` steps with the inputs held; any other step size is fmi2Error.  The FMI 2.0
headers are the Modelica Association's (BSD-2, vendored in ``mitigate/export/csrc/fmi2`` from
fmpy 0.3.32's ``c-code``; fmpy itself is BSD-2, Dassault Systemes), so writing an FMU needs no
fmpy; the tests read the FMU with fmpy.
"""

from __future__ import annotations

import hashlib
import html
import platform
import re
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from models.errors import ConfigError
from models.units import parse_unit
from mitigate.export.files import CMAKE_BUILD_TYPES, check_build_type
from mitigate.export.interface import Interface

__all__ = ["write_fmu", "fmu_tools", "fmu_variables", "input_starts", "unit_definition", "FMI2_SOURCES"]

#: the FMI wrapper and the FMI 2.0 headers (csrc/fmi2/LICENSE.txt)
FMI2_SOURCES = Path(__file__).resolve().parent / "csrc"
FMI2_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
#: FMI's base units (BaseUnit attributes) and the workbench's (models.units: kg, m, s, A, rad)
_BASE = ("kg", "m", "s", "A", "rad")
_TOKEN = re.compile(r"^([A-Za-z]+)(?:\^|\*\*)?(-?\d+)?$")


def unit_definition(unit: str, where: str = "unit") -> tuple[str, dict[str, str]] | None:
    """``(name, BaseUnit attributes)`` of a workbench unit for ``<UnitDefinitions>``, or None for a
    dimensionless one.  The name is written in Modelica's unit syntax (``N m s/rad`` -> ``N.m.s/rad``,
    ``kg m^2`` -> ``kg.m2``, ``rad/s/s`` -> ``rad/s2``, ``ohm`` -> ``Ohm``), which Modelica tools read.

    Raises
    ------
    ConfigError : a unit :func:`models.units.parse_unit` does not know.
    """
    text = unit.strip()
    if text in ("", "-", "1"):
        return None
    num, *dens = text.split("/")
    if len(dens) > 1 and "(" not in text:          # rad/s/s: everything after the first / divides
        text = f"{num}/({' '.join(dens)})"
    u = parse_unit(text, where)
    den = "/".join(dens).strip()
    parts = [(1, num)]
    if den.startswith("(") and den.endswith(")") and "/" in den:      # V/(rad/s) = V s/rad
        b, _, c = den[1:-1].partition("/")
        parts += [(-1, b), (1, c)]
    else:
        parts.append((-1, den.replace("/", " ").replace("(", " ").replace(")", " ")))
    powers: dict[str, int] = {}
    for sign, part in parts:
        for tok in part.replace("*", " ").split():
            if tok == "1":
                continue
            m = _TOKEN.match(tok)
            if m is None:
                raise ConfigError(f"{where}: unit [{unit}] has no FMI name: unexpected {tok!r}")
            sym = "Ohm" if m.group(1) == "ohm" else m.group(1)
            powers[sym] = powers.get(sym, 0) + sign * int(m.group(2) or 1)

    def product(items):
        return ".".join(s + (str(e) if e != 1 else "") for s, e in items)

    top = product((s, e) for s, e in powers.items() if e > 0) or "1"
    bottom = [(s, -e) for s, e in powers.items() if e < 0]
    name = top if not bottom else f"{top}/{product(bottom)}" if len(bottom) == 1 else f"{top}/({product(bottom)})"
    attrs = {b: str(e) for b, e in zip(_BASE, u.dim) if e}
    if u.factor != 1.0:
        attrs["factor"] = repr(u.factor)
    return name, attrs


def fmu_variables(itf: Interface, starts: dict[str, float]) -> list[dict]:
    """The FMU's scalar variables in value-reference order (module docstring of ``fmu_fmi2.c``).

    ``starts`` gives the inputs' start values by in[] name (the programme at t = 0 ...); others 0.
    """
    out = []
    for p in itf.inputs:
        out.append(dict(name=p.name, unit=p.unit, causality="input", doc=p.doc, start=float(starts.get(p.name, 0.0)),
                        variability="discrete" if p.name == "enable" else "continuous"))
    for p in itf.outputs:
        name = p.name if p.name.startswith("estimate:") else f"command:{p.name}"
        out.append(dict(name=name, unit=p.unit, causality="output", variability="discrete", doc=p.doc))
    out.append(dict(name="solve_time", unit="s", causality="output", variability="discrete",
                    doc="wall time of the last OCP solve (0 before the first)"))
    for p in itf.params:
        out.append(dict(name=p.name, unit=p.unit, causality="parameter", variability="fixed", doc=p.doc,
                        start=float(p.value)))
    out.append(dict(name="status", unit="", causality="output", variability="discrete", type="Integer",
                    doc="the last step's status: 0 ok, 1 hold, 2 fallback, 3 failed (the programme's commands)"))
    for vr, v in enumerate(out):
        v["vr"] = vr
    return out


def _model_description(prefix: str, title: str, guid: str, variables: list[dict], dt: float, stop: float,
                       sources: list[str]) -> str:
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": prefix, "guid": guid, "description": title,
        "generationTool": "stickslip-workbench (mitigate export --fmu)", "variableNamingConvention": "flat",
        "numberOfEventIndicators": "0"})
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": prefix, "needsExecutionTool": "false", "canHandleVariableCommunicationStepSize": "true",
        "canInterpolateInputs": "false", "maxOutputDerivativeOrder": "0", "canRunAsynchronuously": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "false", "canSerializeFMUstate": "false", "providesDirectionalDerivative": "false"})
    files = ET.SubElement(cs, "SourceFiles")
    for s in sources:
        ET.SubElement(files, "File", {"name": s})
    units = {}
    for v in variables:
        d = unit_definition(v["unit"], f"export: {v['name']}") if v["unit"] else None
        v["fmi_unit"] = d[0] if d else None
        if d:
            units.setdefault(d[0], d[1])
    ud = ET.SubElement(root, "UnitDefinitions")
    for name, attrs in sorted(units.items()):
        ET.SubElement(ET.SubElement(ud, "Unit", {"name": name}), "BaseUnit", attrs)
    cats = ET.SubElement(root, "LogCategories")
    for c, d in (("logStatusError", "errors: a refused call, a bad step size"),
                 ("logStatusWarning", "warnings: a failed library step")):
        ET.SubElement(cats, "Category", {"name": c, "description": d})
    ET.SubElement(root, "DefaultExperiment", {"startTime": "0", "stopTime": repr(float(stop)), "stepSize": repr(dt)})
    mv = ET.SubElement(root, "ModelVariables")
    for v in variables:
        sv = ET.SubElement(mv, "ScalarVariable", {"name": v["name"], "valueReference": str(v["vr"]),
                                                  "description": v["doc"], "causality": v["causality"],
                                                  "variability": v["variability"]})
        if v["causality"] == "parameter":
            sv.set("initial", "exact")
        attrs = {}
        if v.get("type", "Real") == "Real" and v["fmi_unit"]:
            attrs["unit"] = v["fmi_unit"]
        if "start" in v:
            attrs["start"] = repr(v["start"])
        ET.SubElement(sv, v.get("type", "Real"), attrs)
    ms = ET.SubElement(root, "ModelStructure")
    outs = [str(i + 1) for i, v in enumerate(variables) if v["causality"] == "output"]
    for tag in ("Outputs", "InitialUnknowns"):
        el = ET.SubElement(ms, tag)
        for i in outs:
            ET.SubElement(el, "Unknown", {"index": i})
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _config_header(prefix: str, guid: str, itf: Interface, variables: list[dict], dt: float) -> str:
    P = prefix.upper()
    n_in, n_out, n_par = len(itf.inputs), len(itf.outputs), len(itf.params)
    reals = [v for v in variables if v.get("type", "Real") == "Real"]
    start = [v.get("start", 0.0) for v in reals]
    names = ", ".join('"' + v["name"].replace('"', "'") + '"' for v in reals)
    in_names = [p.name for p in itf.inputs]
    cmds = [p.name for p in itf.outputs if not p.name.startswith("estimate:")]
    cmd_prog = [in_names.index(f"programme:{n}") if f"programme:{n}" in in_names else -1 for n in cmds]
    return f"""/* fmu_config.h: the layout of this FMU (generated by `mitigate export --fmu`; see fmu_fmi2.c). */
#ifndef FMU_CONFIG_H
#define FMU_CONFIG_H
#define LIB_HEADER "{prefix}.h"
#define LIB_TYPE {prefix}
#define LIB(f) {prefix}_##f
#define LIB_FAILED {P}_FAILED
#define FMU_GUID "{guid}"
#define FMU_DT {dt!r}
#define N_IN {n_in}
#define N_OUT {n_out}
#define N_CMD {len(cmds)}
#define N_PAR {n_par}
#define VR_SOLVE_TIME {n_in + n_out}
#define VR_PAR {n_in + n_out + 1}
#define VR_STATUS {n_in + n_out + 1 + n_par}
static const double start_real[{len(reals)}] = {{{", ".join(repr(float(s)) for s in start)}}};
static const char* const real_names[{len(reals)}] = {{{names}}};
static const int cmd_programme[{max(len(cmds), 1)}] = {{{", ".join(map(str, cmd_prog)) or "0"}}};
#endif
"""


def _cmake(prefix: str, sources: list[str], qp: bool = True) -> str:
    """The FMU's CMakeLists.txt (``qp``: link hpipm and blasfeo; the laws need no QP solver)."""
    find = """set(HPIPM_DIR "" CACHE PATH "hpipm and blasfeo for this platform: include/ and lib/")
find_library(HPIPM_LIB hpipm PATHS "${HPIPM_DIR}/lib" NO_DEFAULT_PATH REQUIRED)
find_library(BLASFEO_LIB blasfeo PATHS "${HPIPM_DIR}/lib" NO_DEFAULT_PATH REQUIRED)
""" if qp else ""
    inc = ' "${HPIPM_DIR}/include"' if qp else ""
    link = f'target_link_libraries({prefix} PRIVATE "${{HPIPM_LIB}}" "${{BLASFEO_LIB}}")\n' if qp else ""
    note = "-DHPIPM_DIR=<hpipm and blasfeo: include/ and lib/> " if qp else ""
    return f"""cmake_minimum_required(VERSION 3.13)
project({prefix}_fmu C)
# The FMU's binary: cmake -S sources -B build {note}&& cmake --build build;
# then put {prefix}.<so|dylib|dll>{' with hpipm and blasfeo' if qp else ''} in binaries/<platform>/.
set(CMAKE_C_STANDARD 99)
{CMAKE_BUILD_TYPES}{find}add_library({prefix} SHARED {" ".join(sources)})
target_include_directories({prefix} PRIVATE "${{CMAKE_CURRENT_SOURCE_DIR}}"{inc})
{link}if(NOT MSVC)
  target_compile_options({prefix} PRIVATE -fno-fast-math -ffp-contract=off)
  target_link_libraries({prefix} PRIVATE m)
endif()
# the FMI functions only are exported{'; hpipm and blasfeo are found beside the binary' if qp else ''}
set_target_properties({prefix} PROPERTIES PREFIX "" C_VISIBILITY_PRESET hidden
                      BUILD_WITH_INSTALL_RPATH ON INSTALL_RPATH "$ORIGIN")
if(CMAKE_SYSTEM_NAME STREQUAL "Linux")
  target_link_options({prefix} PRIVATE "-Wl,--version-script=${{CMAKE_CURRENT_SOURCE_DIR}}/fmi2.map")
endif()
"""


def _documentation(prefix: str, title: str, variables: list[dict], dt: float, scenario: str, notes: list[str]) -> str:
    rows = "".join(f"<tr><td>{v['vr']}</td><td><code>{html.escape(v['name'])}</code></td><td>{v['causality']}</td>"
                   f"<td>{v['variability']}</td><td>{html.escape(v['unit'] or '-')}</td>"
                   f"<td>{'' if 'start' not in v else repr(v['start'])}</td><td>{html.escape(v['doc'])}</td></tr>\n"
                   for v in variables)
    items = "".join(f"<li>{html.escape(n)}</li>\n" for n in notes)
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{html.escape(prefix)}</title></head><body>
<h1>{html.escape(prefix)}: {html.escape(title)}</h1>
<p>An FMI 2.0 co-simulation FMU written by <code>mitigate export --fmu</code> from scenario
<code>{html.escape(scenario)}</code>: the same C library as the export folder (no Python at run time).</p>
<h2>Stepping</h2>
<ul>
<li>The DAQ period is {dt!r} s. One <code>fmi2DoStep</code> of <i>h</i> seconds runs the controller's step
<i>h</i> / {dt!r} times (a whole number, else <code>fmi2Error</code>) at t = currentCommunicationPoint + k &middot;
{dt!r} s with the inputs as last set; the outputs are those of the last step. Use a communication step of
one DAQ period to run the controller as on the rig.</li>
<li>The inputs are one DAQ sample: the measured channels (NaN: missing), the programme's values, and
<code>enable</code> (non-zero: the controller sets its commands; zero: the commands are the programme's while
the estimator keeps running, so switching on is bumpless).</li>
<li>The parameters are <i>fixed</i>: set them before <code>fmi2ExitInitializationMode</code> (or after
<code>fmi2Reset</code>); <code>fmi2ExitInitializationMode</code> creates the controller with them.</li>
<li>Before the first step the commands are the programme's and the estimate is zero. <code>status</code>:
0 ok, 1 hold (the last plan held between OCP intervals), 2 fallback, 3 failed (a non-finite output: the
commands are the programme's and <code>fmi2DoStep</code> returns <code>fmi2Warning</code>).</li>
</ul>
<h2>Platforms</h2>
<p><code>binaries/linux64/{prefix}.so</code> is built for {html.escape(platform.system())}
{html.escape(platform.machine())} from <code>sources/</code>; it needs the QP solver hpipm with blasfeo, which
are shared libraries beside it (<code>libhpipm.so</code>, <code>libblasfeo.so.0</code>, found through its RPATH
<code>$ORIGIN</code>), the binaries the casadi wheel ships. For another platform (Windows, macOS, an ARM
real-time target), build hpipm and blasfeo (BSD-2, github.com/giaf) for it, then
<code>cmake -S sources -B build -DHPIPM_DIR=&lt;folder with include/ and lib/&gt; &amp;&amp; cmake --build build</code>
and put the binary with the two libraries in <code>binaries/&lt;platform&gt;/</code>
(<code>win64/{prefix}.dll</code>, <code>darwin64/{prefix}.dylib</code>). <code>sources/</code> lists the C files in
the model description; they compile only together with hpipm's headers.</p>
<h2>Variables</h2>
<table border="1"><tr><th>vr</th><th>name</th><th>causality</th><th>variability</th><th>unit</th><th>start</th>
<th>meaning</th></tr>
{rows}</table>
<h2>What is fixed at export</h2>
<ul>
{items}</ul>
<h2>Licences</h2>
<p>hpipm and blasfeo: BSD-2 (<code>licenses/hpipm.txt</code>, <code>licenses/blasfeo.txt</code>). The FMI 2.0
headers in <code>sources/</code>: BSD-2, Modelica Association (<code>licenses/fmi2.txt</code>).</p>
</body></html>
"""


def fmu_tools() -> str:
    """cmake's path, after checking that an FMU can be built here.

    Raises
    ------
    ConfigError : not 64-bit Linux (the vendored hpipm is the casadi wheel's linux64 binary), or no
        C compiler or cmake.
    """
    if platform.system() != "Linux" or platform.machine() not in ("x86_64", "aarch64"):
        raise ConfigError(f"export: --fmu builds a linux64 binary (the vendored hpipm is the casadi wheel's); this is "
                          f"{platform.system()} {platform.machine()}")
    cmake = shutil.which("cmake")
    if cmake is None or (shutil.which("cc") or shutil.which("gcc")) is None:
        raise ConfigError("export: --fmu builds the FMU's binary and needs a C compiler and cmake (install them "
                          "with the package manager)")
    return cmake


def input_starts(scenario, itf: Interface) -> dict[str, float]:
    """The inputs' start values: the programme and the target speed at t = 0; the channels and
    ``enable`` 0 (the first DAQ sample overrides them all)."""
    sc = scenario
    u0 = sc.programme(0.0)
    out = {f"programme:{n}": float(u0[j]) for j, n in enumerate(sc.model.inputs)}
    if any(p.name == "target_speed" for p in itf.inputs):
        out["target_speed"] = float(sc.control.speed(0.0)) if sc.control.speed is not None else sc.model.nominal_speed()
    return out


def write_fmu(folder: Path, prefix: str, itf: Interface, scenario, *, title: str, notes: list[str],
              build_type: str = "Release") -> str:
    """Build and write ``folder/<prefix>.fmu`` from an export folder (``src/``, ``include/``, ``vendor/``).

    Parameters
    ----------
    folder : the export folder (complete but for the FMU)
    prefix : the C prefix, the FMU's modelIdentifier
    itf : the layout of in[], out[], params[]
    scenario : the :class:`mitigate.scenario.Scenario` exported (its DAQ period, duration, programme)
    title : one line on what is exported
    notes : what is fixed at export (the library's README's list)

    Returns
    -------
    str : the FMU's file name, relative to ``folder``

    Raises
    ------
    ConfigError : not on linux64, or no C compiler / cmake.
    RuntimeError : the build failed (the tool's last lines).
    """
    cmake = fmu_tools()
    dt, stop = float(scenario.dt), float(scenario.duration)
    with open(folder / "README.md", "a") as f:
        f.write(f"""
## The FMU (`{prefix}.fmu`)

An FMI 2.0 co-simulation FMU of this library (`mitigate export --fmu`): every in[] entry is an
input, the commands are the outputs `command:<input>`, the estimate `estimate:<state>`, the runtime
parameters are fixed parameters (set before `fmi2ExitInitializationMode`).  One `fmi2DoStep` of n
DAQ periods runs n steps; another step size is `fmi2Error`.  `binaries/linux64/` holds the binary
with hpipm and blasfeo beside it; `sources/` and `documentation/index.html` say how to build it for
another platform.
""")
    variables = fmu_variables(itf, input_starts(scenario, itf))
    files: dict[str, bytes] = {}
    src = sorted((folder / "src").iterdir()) + [folder / "include" / f"{prefix}.h"]
    for p in src:
        files[f"sources/{p.name}"] = p.read_bytes()
    for h in FMI2_HEADERS:
        files[f"sources/{h}"] = (FMI2_SOURCES / "fmi2" / h).read_bytes()
    files["sources/fmu_fmi2.c"] = (FMI2_SOURCES / "fmu_fmi2.c").read_bytes()
    files["sources/fmi2.map"] = b"{ global: fmi2*; local: *; };\n"
    c_files = sorted(n.partition("/")[2] for n in files if n.endswith(".c"))
    qp = (folder / "vendor" / "lib" / "libhpipm.so").exists()
    files["sources/CMakeLists.txt"] = _cmake(prefix, c_files, qp).encode()
    # the GUID identifies this interface and these sources: the same export gives the same GUID
    digest = hashlib.sha256(repr([(v["name"], v["vr"], v.get("start")) for v in variables]).encode())
    for name in sorted(files):
        digest.update(name.encode() + files[name])
    guid = "{" + str(uuid.UUID(bytes=digest.digest()[:16], version=4)) + "}"
    files["sources/fmu_config.h"] = _config_header(prefix, guid, itf, variables, dt).encode()
    files["modelDescription.xml"] = _model_description(prefix, title, guid, variables, dt, stop, c_files).encode()
    files["documentation/index.html"] = _documentation(prefix, title, variables, dt, scenario.where, notes).encode()
    files["documentation/README.md"] = (folder / "README.md").read_bytes()
    files["documentation/licenses/fmi2.txt"] = (FMI2_SOURCES / "fmi2" / "LICENSE.txt").read_bytes()
    for lic in sorted((folder / "vendor" / "LICENSES").glob("*.txt")):
        files[f"documentation/licenses/{lic.name}"] = lic.read_bytes()
    with tempfile.TemporaryDirectory(prefix=".fmu_") as tmp:
        tmp = Path(tmp)
        for name, data in files.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_bytes(data)
        build = tmp / "build"
        hp = [f"-DHPIPM_DIR={(folder / 'vendor').resolve()}"] if qp else []
        for cmd in ([cmake, "-S", str(tmp / "sources"), "-B", str(build), f"-DCMAKE_BUILD_TYPE={check_build_type(build_type)}", *hp],
                    [cmake, "--build", str(build)]):
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode:
                raise RuntimeError(f"building the FMU: {' '.join(cmd[:2])} failed: {(r.stdout + r.stderr)[-800:]}")
        files[f"binaries/linux64/{prefix}.so"] = (build / f"{prefix}.so").read_bytes()
    for lib in ("libhpipm.so", "libblasfeo.so.0") if qp else ():
        files[f"binaries/linux64/{lib}"] = (folder / "vendor" / "lib" / lib).read_bytes()
    name = f"{prefix}.fmu"
    with zipfile.ZipFile(folder / name, "w", zipfile.ZIP_DEFLATED) as z:
        for n in sorted(files):
            info = zipfile.ZipInfo(n, date_time=(2020, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = (0o755 if n.startswith("binaries/") else 0o644) << 16
            z.writestr(info, files[n])
    return name
