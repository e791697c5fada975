"""A fuzz set of the kinds issue 20 lists, through the CLI: bad inputs, misbehaving plug-ins, output
folders, concurrency, kills.  Each case says what must happen (exit code, one line naming the field, what
is or is not written, which processes are left); a tiny scenario (2 s) keeps it fast.

Cases run through ``mitigate.cli.main`` in this process (fast) unless they need processes of their own
(worker isolation, two commands at once, SIGKILL, Ctrl-C): those start ``python -m mitigate.cli``.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import mitigate.cli as cli
from models.files import MARKER_NAME, output_set

ROOT = Path(__file__).resolve().parents[1]
PY = [sys.executable, "-m", "mitigate.cli"]

TINY = """
[scenario]
name = "{name}"
duration = {duration}
seed = 1

[inputs]
omega_ref = "30 rpm"
n1 = {n1}

[control]
start = {start}

[estimator]
kind = "fd"

[[controllers]]
name = "PI only"
kind = "pi"
{extra}
"""

SUITE = """
[suite]
name = "tiny"
scenarios = ["tiny.toml"]

[[controllers]]
name = "PI only"
kind = "pi"
{extra}
"""


def tiny(name="tiny", duration=2.0, n1="20.0", start=1.0, extra=""):
    return TINY.format(name=name, duration=duration, n1=n1, start=start, extra=extra)


def bad(kind, **options):
    opts = "".join(f"\n{k} = {v!r}" for k, v in options.items()).replace("'", '"')
    return f'[[controllers]]\nname = "bad"\nkind = "tests.plugins.faulty:{kind}"{opts}\n'


@pytest.fixture
def ws(tmp_path, monkeypatch):
    """A working folder with the tiny scenario, a suite of it, a log and a parameter file."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(ROOT))
    monkeypatch.setenv("PYTHONPATH", str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    (tmp_path / "tiny.toml").write_text(tiny())
    (tmp_path / "suite.toml").write_text(SUITE.format(extra=""))
    (tmp_path / "a_file").write_text("not a folder\n")
    (tmp_path / "log.csv").write_text("t [s],omega1 [rad/s]\n0,0\n0.01,0\n")
    return tmp_path


def main(*argv):
    return cli.main([str(a) for a in argv])


def one_line_error(capsys, *needles):
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


# ----------------------------------------------------------------------------- output folders
#: (command, argv before --out, the --out that is a FILE for it ("" = a folder output))
COMMANDS = {
    "run": (["run", "tiny.toml"], ""),
    "simulate": (["simulate", "tiny.toml"], ""),
    "sweep": (["sweep", "tiny.toml", "--vary", "n1=5:40:2", "--duration", "1", "--no-stability"], ""),
    "benchmark": (["benchmark", "suite.toml"], ""),
    "modal": (["modal", "--variant", "free", "--no-map"], ""),
    "estimate": (["estimate", "log.csv", "--estimator", "fd"], "est.csv"),
    "identify": (["identify", "log.csv", "--model", "rig3", "--free", "k1"], "fit.toml"),
}


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize("case", ["out_is_a_file", "parent_is_a_file", "out_not_writable"])
def test_an_unusable_output_location_is_one_line_and_exit_2_before_any_work(ws, capsys, command, case):
    args, file_out = COMMANDS[command]
    target = {"out_is_a_file": "a_file" if not file_out else "sub",
              "parent_is_a_file": f"a_file/{file_out or 'out'}",
              "out_not_writable": f"/proc/stickslip_fuzz/{file_out or 'out'}"}[case]
    if case == "out_is_a_file" and file_out:
        (ws / "sub").mkdir()                     # a file output given a folder
    t0 = time.perf_counter()
    assert main(*args, "--out", target) == 2
    one_line_error(capsys, f"mitigate {command}: error:")
    assert time.perf_counter() - t0 < 15
    assert sorted(p.name for p in ws.iterdir()) == sorted(["tiny.toml", "suite.toml", "a_file", "log.csv"]
                                                          + (["sub"] if case == "out_is_a_file" and file_out else []))


@pytest.mark.slow
@pytest.mark.parametrize("command", ["run", "simulate", "benchmark"])
def test_existing_outputs_are_refused_without_force_and_nothing_is_run(ws, capsys, command):
    out = ws / "o"
    assert main(*COMMANDS[command][0], "--out", out) == 0
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    capsys.readouterr()
    assert main(*COMMANDS[command][0], "--out", out) == 2
    one_line_error(capsys, "file exists", "--force")
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    assert not any(n.startswith(".mitigate") for n in before)          # no lock or staging left behind


@pytest.mark.slow
def test_a_busy_output_folder_is_refused(ws, capsys):
    with output_set(ws / "o", []):                  # another command holds the folder
        assert main("run", "tiny.toml", "--out", ws / "o") == 2
        one_line_error(capsys, "is in use by another mitigate command", f"(process {os.getpid()})")
    assert main("run", "tiny.toml", "--out", ws / "o") == 0       # free again


@pytest.mark.slow
def test_two_runs_into_one_folder_at_once_never_mix_files(ws):
    (ws / "a.toml").write_text(tiny(name="a", duration=3.0, extra=bad("Follow")))
    (ws / "b.toml").write_text(tiny(name="b", duration=3.0, extra='[[controllers]]\nname = "brake"\nkind = "brake"\n'))
    procs = [subprocess.Popen(PY + ["run", f"{n}.toml", "--out", "o", "--jobs", "1", "--json"], cwd=ws,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for n in "ab"]
    outs = [p.communicate(timeout=120) for p in procs]
    codes = sorted(p.returncode for p in procs)
    assert codes == [0, 2], outs
    winner = json.loads(next(o for (o, _), p in zip(outs, procs) if p.returncode == 0))
    names = sorted(c["name"] for c in winner["controllers"])
    logs = sorted(p.name for p in (ws / "o").glob("log_*.csv"))
    assert logs == sorted(f"log_{n.lower().replace(' ', '_')}.csv" for n in names)
    assert json.loads((ws / "o" / "metrics.json").read_text())["scenario"] == winner["scenario"]


@pytest.mark.slow
def test_a_run_killed_while_writing_leaves_the_folder_as_it_was_and_the_rerun_needs_no_force(ws, capsys, monkeypatch):
    import mitigate.plots as plots
    real = plots.plot_metric_bars

    def killed(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(plots, "plot_metric_bars", killed)
    assert main("run", "tiny.toml", "--out", "o") == 130
    assert not (ws / "o").exists()                                # nothing half-written
    monkeypatch.setattr(plots, "plot_metric_bars", real)
    assert main("run", "tiny.toml", "--out", "o") == 0
    assert (ws / "o" / "metrics.json").is_file() and (ws / "o" / "metrics.png").is_file()


@pytest.mark.slow
def test_a_forced_rerun_leaves_no_file_of_the_older_set_mixed_in(ws, capsys):
    (ws / "s.toml").write_text(tiny(extra=bad("Follow")))
    assert main("run", "s.toml", "--out", "o", "--jobs", "1") == 0
    assert (ws / "o" / "log_bad.csv").is_file()
    (ws / "s.toml").write_text(tiny(extra=bad("InitRaises")))      # now "bad" fails before it has a log
    assert main("run", "s.toml", "--out", "o", "--jobs", "1", "--force") == 1
    assert not (ws / "o" / "log_bad.csv").exists() and not (ws / "o" / "timeseries_bad.png").exists()
    doc = json.loads((ws / "o" / "metrics.json").read_text())
    assert {c["name"]: c["status"] for c in doc["controllers"]} == {"PI only": "ok", "bad": "failed"}


@pytest.mark.slow
def test_a_set_marked_incomplete_by_a_killed_commit_is_replaced_without_force(ws, capsys):
    out = ws / "o"
    assert main("run", "tiny.toml", "--out", out) == 0
    (out / MARKER_NAME).write_text(json.dumps({"pid": 1, "names": ["metrics.csv", "report.md"]}))
    (out / "metrics.json").unlink()                                # the commit died between two moves
    (out / "metrics.csv").write_text("half\n")
    capsys.readouterr()
    assert main("run", "tiny.toml", "--out", out) == 2          # the other files are whole: --force still needed
    one_line_error(capsys, "file exists")
    assert main("run", "tiny.toml", "--out", out, "--force") == 0
    assert not (out / MARKER_NAME).exists() and (out / "metrics.csv").read_text().startswith("controller,")


def test_a_killed_commit_with_only_its_own_files_left_is_replaced_without_force(ws, capsys):
    out = ws / "o"
    assert main("simulate", "tiny.toml", "--out", out, "--no-plot") == 0
    (out / MARKER_NAME).write_text(json.dumps({"pid": 1, "names": ["tiny.csv"]}))
    (ws / "o" / ".mitigate-staging-999999").mkdir()               # a dead process's staging folder
    assert main("simulate", "tiny.toml", "--out", out, "--no-plot") == 0
    assert sorted(p.name for p in out.iterdir()) == ["tiny.csv"]


@pytest.mark.parametrize("name", ["ABSOLUTE", "../escape", "a/b", "..", "x\ty"])
@pytest.mark.parametrize("command", ["simulate", "sweep"])
def test_a_scenario_name_never_writes_outside_out(ws, capsys, name, command):
    name = str(ws.parent / "escape") if name == "ABSOLUTE" else name        # an absolute path
    (ws / "evil.toml").write_text(tiny(name=name.replace("\t", "\\t")))
    args = ["simulate", "evil.toml", "--out", "o"] if command == "simulate" else \
        ["sweep", "evil.toml", "--vary", "n1=5:40:2", "--duration", "1", "--no-stability"]
    assert main(*args) == 2
    one_line_error(capsys, "scenario.name must be usable as a file name")
    assert not list(ws.parent.glob("escape*"))
    assert sorted(p.name for p in ws.iterdir()) == sorted(["tiny.toml", "suite.toml", "a_file", "log.csv", "evil.toml"])


def test_a_log_profile_naming_a_foreign_file_never_echoes_its_content(ws, capsys):
    secret = ws / "secret.txt"
    secret.write_text("root:hunter2:0:0:root:/root:/bin/bash\nsecond line\n")
    (ws / "s.toml").write_text(tiny(n1=f'{{kind = "log", file = "{secret}", channel = "n1"}}'))
    assert main("run", "s.toml", "--out", "o") == 2
    err = one_line_error(capsys, "inputs.n1", "header column 1 must look like 'name [unit]'")
    assert "hunter2" not in err and "bin/bash" not in err and "second line" not in err


# ----------------------------------------------------------------------------- sizes and numbers
BIG = "[" + ", ".join(f"{1.5 * i}" for i in range(100_000)) + "]"


@pytest.mark.slow
@pytest.mark.parametrize("field, old, new", [
    ("scenario.duration", "duration = 2.0", f"duration = {BIG}"),
    ("scenario.seed", "seed = 1", f"seed = {BIG}"),
    ("scenario.name", 'name = "tiny"', f"name = {BIG}"),
    ("inputs.n1", "n1 = 20.0", f"n1 = {BIG}"),
    ("control.start", "start = 1.0", f"start = {BIG}"),
    ("estimator.q_stick", 'kind = "fd"', f'kind = "ekf"\nq_stick = {BIG}'),
    ("controller 2 'b'.gain_overspeed", 'kind = "pi"', f'kind = "pi"\n[[controllers]]\nname = "b"\nkind = "brake"\n'
                                                     f'gain_overspeed = {BIG}'),
])
def test_a_huge_array_in_the_wrong_place_is_quoted_in_80_characters(ws, capsys, field, old, new):
    text = tiny()
    assert old in text
    (ws / "big.toml").write_text(text.replace(old, new, 1))
    assert main("run", "big.toml", "--out", "o") == 2
    err = one_line_error(capsys, field)
    assert len(err) < 400 and ("(100000 items)" in err or "unknown" in err)


@pytest.mark.parametrize("vary", [["n1=5:40:1000000000"], ["n1=5:40:100000", "omega_ref=1:8:100000"],
                                  ["n1=5:40:1000", "omega_ref=1:8:1000", "k1_scale=1:2:1000"]])
def test_a_sweep_of_a_billion_points_is_refused_before_allocation(ws, capsys, vary):
    t0 = time.perf_counter()
    args = [a for v in vary for a in ("--vary", v)]
    assert main("sweep", "tiny.toml", *args, "--out", "o") == 2
    one_line_error(capsys, "--vary", "1,000,000")
    assert time.perf_counter() - t0 < 5 and not (ws / "o").exists()


def test_control_start_after_the_end_is_refused(ws, capsys):
    (ws / "late.toml").write_text(tiny(start=5.0))
    assert main("run", "late.toml", "--out", "o") == 2
    one_line_error(capsys, "control.start must be < scenario.duration = 2 s")


def test_a_daq_period_longer_than_the_run_is_refused_and_nothing_is_written(ws, capsys):
    """Issue 28: dt = 0.01 s with a 0.004 s duration ran, wrote metrics and plots, and exited 1."""
    (ws / "short.toml").write_text(tiny(duration=0.004, start=0.0))
    assert main("run", "short.toml", "--out", "o") == 2
    one_line_error(capsys, "scenario.dt must be <= scenario.duration = 0.004 s")
    assert not (ws / "o").exists()


def test_a_parameter_file_error_keeps_the_path_out_of_the_field_name(ws, capsys):
    rig = ws / "myrig.toml"
    rig.write_text((ROOT / "models/rigs/rig3.toml").read_text())
    (ws / "p.toml").write_text('model = "myrig.toml"\nbase = "published"\n[params]\nJ2 = -1.0\n')
    assert main("modal", "--model", rig, "--params", "p.toml") == 2
    err = one_line_error(capsys, "params.J2 must be")
    assert f"params.{rig}" not in err and "myrig.toml.J2" not in err


# ----------------------------------------------------------------------------- plug-ins through the CLI
@pytest.mark.slow
@pytest.mark.parametrize("kind, why", [          # every kind in the library: test_faults_plugins.py
    ("InitRaises", "RuntimeError: boom in __init__"),
    ("StepRaises", "ValueError: boom in step"),
    ("Exits", "SystemExit: exit code 3"),
])
def test_a_misbehaving_plug_in_fails_its_run_and_the_command_exits_1(ws, capsys, kind, why):
    (ws / "s.toml").write_text(tiny(extra=bad(kind)))
    assert main("run", "s.toml", "--out", "o", "--jobs", "1", "--json") == 1
    doc = json.loads(capsys.readouterr().out)
    st = {c["name"]: (c["status"], c["message"]) for c in doc["controllers"]}
    assert st["PI only"] == ("ok", "ok") and st["bad"][0] == "failed" and why in st["bad"][1]
    assert doc["status"] == "failed"


def test_an_abstract_plug_in_is_exit_2_before_anything_runs(ws, capsys):
    (ws / "s.toml").write_text(tiny(extra=bad("Abstract")))
    assert main("run", "s.toml", "--out", "o") == 2
    one_line_error(capsys, "controller 2 'bad'.kind: 'tests.plugins.faulty:Abstract' is abstract")
    assert not (ws / "o").exists()


@pytest.mark.slow
def test_a_failing_plug_in_in_the_benchmark_fails_its_cell_and_the_command_exits_1(ws, capsys):
    assert main("benchmark", "suite.toml", "--out", "o", "--jobs", "1", "--json", "--quick",
                "--controller", "Bad=tests.plugins.faulty:StepRaises",
                "--controller", "Late=tests.plugins.faulty:SlowEvery,every=5,seconds=0.03") == 1
    doc = json.loads(capsys.readouterr().out)
    entries = {e["controller"]: e for e in doc["entries"]}
    bad_ = entries["Bad"]
    assert bad_["n_runs"] == 1 and bad_["n_failed"] == 1 and not bad_["job_done"]
    assert bad_["messages"] == ["controller failed at t = 1.000 s in step: ValueError: boom in step"]
    # the benchmark's compute model has no wall-clock deadline: a slow answer is applied one control
    # period late like every other, and is no miss (the machine's speed does not enter the results)
    assert entries["Late"]["n_failed"] == 0 and entries["Late"]["messages"] == []
    assert "controller_deadline_misses" not in entries["Late"]["counts"]
    assert entries["PI only"]["n_failed"] == 0 and entries["PI only"]["messages"] == []
    assert doc["status"] == "failed"
    # it set nothing before failing: classed "none" (the inputs it moved away from the programme)
    assert ("**Bad** (none class): job NOT done (1 of 1 runs: 1 failed); every run failed (controller failed "
            "at t = 1.000 s in step: ValueError: boom in step)") in \
        (ws / "o" / "ranking.md").read_text()


def _cli(ws, *args, timeout=120):
    return subprocess.run(PY + [str(a) for a in args], cwd=ws, capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_in_worker_processes_a_dying_worker_or_a_hang_fails_only_its_run(ws):
    (ws / "s.toml").write_text(tiny(extra=bad("KillsWorker") + bad("Sleeps", seconds=30.0).replace('"bad"', '"slow"')
                                    + bad("Prints").replace('"bad"', '"noisy"'))
                               .replace("start = 1.0", 'start = 1.0\ntimeout = "1 s"'))
    t0 = time.perf_counter()
    p = _cli(ws, "run", "s.toml", "--out", "o", "--jobs", "2", "--json")
    assert p.returncode == 1 and time.perf_counter() - t0 < 60
    doc = json.loads(p.stdout)                                       # a printing plug-in does not spoil --json
    st = {c["name"]: (c["status"], c["message"]) for c in doc["controllers"]}
    assert st["PI only"] == ("ok", "ok") and st["noisy"] == ("ok", "ok")
    assert st["bad"] == ("failed", "its worker process died (exit code 7)")
    assert st["slow"] == ("failed", "controller failed at t = 1.000 s in step: TimeoutError: step did not return "
                                    "within 1 s")
    assert "garbage on stdout" in p.stderr


# ----------------------------------------------------------------------------- kills and Ctrl-C
def _group(pgid):
    """Live (not zombie) processes of the process group ``pgid``, from /proc."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue                       # gone meanwhile
        state, pgrp = fields[0], int(fields[2])
        if pgrp == pgid and state != "Z":
            found.append((int(d.name), state))
    return found


def _as_from_a_terminal():
    """In the command's process before it starts: SIGINT and SIGTERM at their defaults and unblocked, as
    a shell starts a foreground command, whatever this test process inherited or was left with by an
    earlier test in the same pytest-xdist worker (a command started with SIGINT ignored keeps it
    ignored: seen as a Ctrl-C test's `mitigate run` running on to exit 0 in two suite runs)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})


def _signal_state(pid="self") -> str:
    """The ignored and blocked signal masks of a process (/proc), for a failure's message."""
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return "?"
    return " ".join(ln.replace("\t", "") for ln in lines if ln.startswith(("SigIgn", "SigBlk")))


def _start(ws, args):
    p = subprocess.Popen(PY + args, cwd=ws, start_new_session=True, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True, preexec_fn=_as_from_a_terminal)
    t0 = time.time()
    while time.time() - t0 < 60 and len(_group(p.pid)) < 4:      # the command, the tracker and 2 workers
        time.sleep(0.1)
    assert len(_group(p.pid)) >= 4, "the workers did not start"
    time.sleep(1.0)
    return p


def _gone(pgid, within=5.0):
    t0 = time.time()
    while time.time() - t0 < within:
        if not _group(pgid):
            return True
        time.sleep(0.1)
    return not _group(pgid)


linux = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc (and PR_SET_PDEATHSIG)")


@pytest.mark.slow
@linux
@pytest.mark.parametrize("command", ["run", "sweep", "benchmark"])
def test_sigkill_leaves_no_process_of_the_command_after_5_s(ws, command):
    (ws / "long.toml").write_text(tiny(name="long", duration=60.0, extra=bad("Follow")))
    (ws / "suite_long.toml").write_text(SUITE.format(extra=bad("Follow")).replace("tiny.toml", "long.toml"))
    args = {"run": ["run", "long.toml", "--out", "o", "--jobs", "2"],
            "sweep": ["sweep", "long.toml", "--vary", "n1=5:40:8", "--duration", "30", "--chunk", "2",
                      "--workers", "2", "--out", "o", "--no-stability"],
            "benchmark": ["benchmark", "suite_long.toml", "--out", "o", "--jobs", "2"]}[command]
    p = _start(ws, args)
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    assert _gone(p.pid), _group(p.pid)
    if command != "sweep":                         # nothing visible was written; the rerun cleans up
        left = {n for n in os.listdir(ws / "o") if not n.startswith(".mitigate")} if (ws / "o").exists() else set()
        # the benchmark keeps its finished runs (its resumable store: manifest.json, runs/), never a report file
        assert left <= ({"manifest.json", "runs"} if command == "benchmark" else set()), left


@pytest.mark.slow
@linux
def test_ctrl_c_ends_cleanly_with_no_process_and_nothing_written(ws):
    (ws / "long.toml").write_text(tiny(name="long", duration=60.0, extra=bad("Follow")))
    p = _start(ws, ["run", "long.toml", "--out", "o", "--jobs", "2"])
    os.killpg(p.pid, signal.SIGINT)                  # what a terminal does: the whole foreground group
    _, err = p.communicate(timeout=30)
    assert p.returncode == 130 and err.strip().splitlines()[-1] == "mitigate run: interrupted", \
        (err, "this test process:", _signal_state())
    assert "Traceback" not in err
    assert _gone(p.pid) and not (ws / "o").exists()
