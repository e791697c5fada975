"""A design value is labelled as the rig file's value (issue 28, item 5).

Outputs called any rig file's parameter set "published parameters", a user's own bench included.
They now say "the rig file's values (<rig name>)"; where parameters are listed one by one
(``mitigate identify``), each shows its ``source``, which says when it is a publication (rig3's
"thesis Table 3.1").  ``rig.published()`` stays the API's name, and ``"published"`` the input keyword
of ``plant.params`` and ``base``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from mitigate.cli import main
from models import get_model

ROOT = Path(__file__).resolve().parents[1]


def test_modal_names_the_rig_files_values(capsys, tmp_path):
    rig = tmp_path / "my_bench.toml"
    rig.write_text((ROOT / "models/rigs/disc.toml").read_text().replace('name = "disc"', 'name = "my_bench"'))
    assert main(["modal", "--model", str(rig), "--variant", "free"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "modal analysis of my_bench (the rig file's values (my_bench))"
    assert "published" not in out
    assert main(["modal", "--model", str(rig), "--variant", "free", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["params"] == "the rig file's values (my_bench)"
    assert get_model("rig3").values_label == "the rig file's values (rig3)"


def test_no_output_text_calls_a_rig_files_values_published():
    """Outside the input keyword ``"published"`` (scenario ``plant.params``, parameter-file ``base``)
    and the API name ``published()``, no string literal of the CLI, the runner or the report says it."""
    allowed = re.compile(r"""\.published\(|\\?["']published\\?["']""")
    hits = []
    for f in sorted((ROOT / "mitigate").rglob("*.py")):
        for n, line in enumerate(f.read_text().splitlines(), 1):
            for lit in re.findall(r'"(?:[^"\\]|\\.)*"' + r"|'(?:[^'\\]|\\.)*'", line.split("  # ", 1)[0]):
                if "published" in allowed.sub("", lit):
                    hits.append(f"{f.relative_to(ROOT)}:{n}: {lit}")
    assert not hits, "\n".join(hits)
