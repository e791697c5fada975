"""With ``--json``, a command that ends without a result still prints one JSON document on stdout
(``mitigate.cli.error_document``), beside its one line on stderr; without ``--json`` stdout stays empty."""

from __future__ import annotations

import json

import pytest

from mitigate.cli import main


def _document(capsys):
    out, err = capsys.readouterr()
    return json.loads(out), err


def test_bad_input_with_json_is_a_document(capsys):
    rc = main(["modal", "--model", "no_such_rig", "--json"])
    doc, err = _document(capsys)
    assert rc == 2
    assert doc["status"] == "error" and doc["kind"] == "input" and doc["exit_code"] == 2
    assert doc["command"] == "modal"
    assert doc["message"] == err.strip()            # the same one line as on stderr
    assert "no_such_rig" in doc["message"] and err.count("\n") == 1


def test_usage_error_with_json_is_a_document(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["modal", "--no-such-flag", "--json"])
    doc, err = _document(capsys)
    assert exc.value.code == 2
    assert doc["kind"] == "usage" and doc["command"] == "modal" and doc["exit_code"] == 2
    assert "--no-such-flag" in doc["message"] and doc["message"] == err.strip()


def test_without_json_stdout_stays_empty(capsys):
    assert main(["modal", "--model", "no_such_rig"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("mitigate modal: error: ")
