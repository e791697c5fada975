"""The compiled steps' build types (``STICKSLIP_BUILD_TYPE``, models.codegen.BUILD_TYPES): one
declaration read by the workbench's compiled steps and by the exports; a bad value is a one-line
refusal naming the variable, exit code 2 from a command, nothing written."""

from pathlib import Path

import pytest

from models import codegen
from models.cbuild import C_FLAGS, c_flags
from models.errors import ConfigError
from mitigate.export.files import BUILD_TYPES as EXPORT_BUILD_TYPES

ROOT = Path(__file__).resolve().parent.parent


def test_one_declaration_for_the_steps_and_the_exports():
    assert EXPORT_BUILD_TYPES is codegen.BUILD_TYPES
    assert set(codegen.BUILD_TYPES) == {"Release", "Debug"}


@pytest.mark.parametrize("value, opt", [(None, ["-O2"]), ("Release", ["-O2"]), ("Debug", ["-O0", "-g"])])
def test_the_flags_follow_the_build_type(monkeypatch, value, opt):
    if value is None:
        monkeypatch.delenv("STICKSLIP_BUILD_TYPE", raising=False)
    else:
        monkeypatch.setenv("STICKSLIP_BUILD_TYPE", value)
    assert c_flags() == [*opt, *C_FLAGS]
    assert "-ffp-contract=off" in C_FLAGS and "-fno-fast-math" in C_FLAGS     # both round alike


def test_debug_information_names_no_build_folder():
    assert codegen.reproducible(["-O0", "-g"], "/tmp/x") == ["-O0", "-g", "-fdebug-prefix-map=/tmp/x=."]
    assert codegen.reproducible(["-O2"], "/tmp/x") == ["-O2"]


@pytest.mark.slow
def test_a_bad_build_type_is_one_line_and_exit_2_with_nothing_written(monkeypatch, tmp_path, capsys, main):
    monkeypatch.setenv("STICKSLIP_BUILD_TYPE", "Fast")
    with pytest.raises(ConfigError, match=r"^STICKSLIP_BUILD_TYPE: expected one of Release, Debug; got 'Fast'$"):
        codegen.build_type()
    out = tmp_path / "o"
    assert main(["run", str(ROOT / "scenarios" / "stick_slip_30rpm.toml"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "STICKSLIP_BUILD_TYPE: expected one of Release, Debug; got 'Fast'" in err[0], err
    assert not out.exists()
