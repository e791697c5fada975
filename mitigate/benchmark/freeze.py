"""A frozen suite: what a suite version ties together, and the check that nothing moved under it.

Suite v1 (``scenarios/benchmark/suite.toml``, ``[suite] version = "1"``) is frozen by its lock file
``suite.lock.json`` beside it: the SHA-256 of the suite file, of every scenario file and of every rig
file they use, the metrics version (:data:`mitigate.metrics.METRICS_VERSION`) and the hash of the code
that computes the metrics (``mitigate/metrics/*.py``, ``mitigate/severity.py``, ``models/sensors.py``),
and of the results' schema.  Two entries are comparable when they ran the same suite version under the
same metrics version and compute model; the lock makes sure that the version means the same files.

:func:`check` lists every difference between a suite and its lock (``tests/test_benchmark_standard.py``
keeps the shipped suite equal to its lock).  A change to a scenario or a rig is a new suite version, a
change to what a metric computes a new ``METRICS_VERSION``: bump it, then write the lock again (a change
to the metric code that computes the same numbers -- a description, where a column is shown -- only
rewrites the lock, and the reviewer sees it in the lock's diff)::

    python -m mitigate.benchmark.freeze scenarios/benchmark/suite.toml --write
"""

from __future__ import annotations

import hashlib
import json
import sys
from importlib import resources
from pathlib import Path

from models.checks import read_toml
from models.errors import DataError

__all__ = ["fingerprint", "check", "lock_path", "write_lock", "METRIC_CODE"]

#: the code whose hash the lock keeps as the metric code (relative to the source root)
METRIC_CODE = ("mitigate/metrics/*.py", "mitigate/severity.py", "models/sensors.py")


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _root() -> Path:
    return Path(__file__).resolve().parents[2]


def metric_code_hash() -> str:
    """SHA-256 over the metric code's files (:data:`METRIC_CODE`), by relative name and content."""
    h = hashlib.sha256()
    root = _root()
    for pattern in METRIC_CODE:
        for p in sorted(root.glob(pattern)):
            h.update(p.relative_to(root).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def lock_path(suite_path) -> Path:
    """The lock file of a suite file (``suite.lock.json`` beside ``suite.toml``)."""
    p = Path(suite_path)
    return p.with_name(p.stem + ".lock.json")


def schema() -> dict:
    """The results' JSON Schema (``mitigate/benchmark/results.schema.json``), part of a suite version."""
    return json.loads(resources.files("mitigate.benchmark").joinpath("results.schema.json").read_text())


def fingerprint(suite_path) -> dict:
    """What a suite version ties together (module docstring), as a JSON-serialisable dict."""
    from mitigate.metrics import METRICS_VERSION
    from models.rig import RIGS_DIR, rig_key

    suite_path = Path(suite_path)
    raw = read_toml(suite_path, "benchmark suite")
    s = raw.get("suite", {})
    files = {suite_path.name: _sha(suite_path.read_bytes())}
    rigs = {}
    for f in s.get("scenarios", []):
        p = suite_path.parent / f
        files[f] = _sha(p.read_bytes())
        model = read_toml(p, "scenario file").get("scenario", {}).get("model", "")
        cand = p.parent / model
        rig = cand if str(model).endswith(".toml") and cand.exists() else RIGS_DIR / f"{rig_key(model)}.toml"
        rigs[rig.name] = _sha(rig.read_bytes())
    return {"suite": str(s.get("name", suite_path.stem)), "version": str(s.get("version", "")),
            "compute": str(s.get("compute", "period")), "metrics_version": METRICS_VERSION,
            "metrics_code": metric_code_hash(), "schema": _sha(json.dumps(schema(), sort_keys=True).encode()),
            "files": files, "rigs": dict(sorted(rigs.items()))}


def write_lock(suite_path) -> Path:
    """Write the suite's lock file (:func:`lock_path`) from :func:`fingerprint`."""
    p = lock_path(suite_path)
    p.write_text(json.dumps(fingerprint(suite_path), indent=2) + "\n")
    return p


def check(suite_path) -> list[str]:
    """Every difference between a suite (its files, rigs, metric code and schema) and its lock, one line
    each; empty when it is as frozen.

    Raises
    ------
    DataError : the suite has no lock file, or it is not JSON.
    """
    p = lock_path(suite_path)
    try:
        lock = json.loads(p.read_text())
    except OSError:
        raise DataError(f"{p}: no lock file: the suite is not frozen (python -m mitigate.benchmark.freeze "
                        f"{suite_path} --write)") from None
    except ValueError as exc:
        raise DataError(f"{p}: not JSON ({exc})") from None
    now = fingerprint(suite_path)
    out = []
    for key in ("suite", "version", "compute", "metrics_version", "metrics_code", "schema"):
        if lock.get(key) != now[key]:
            out.append(f"{key}: locked {lock.get(key)!r}, now {now[key]!r}")
    for group in ("files", "rigs"):
        a, b = lock.get(group, {}), now[group]
        for name in sorted(set(a) | set(b)):
            if a.get(name) != b.get(name):
                what = "added" if name not in a else "removed" if name not in b else "changed"
                out.append(f"{group}: {name} {what}")
    return out


def main(argv=None) -> int:
    """``python -m mitigate.benchmark.freeze SUITE [--write]``: check a suite against its lock, or write it."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0].startswith("-"):
        print("usage: python -m mitigate.benchmark.freeze SUITE.toml [--write]", file=sys.stderr)
        return 2
    if "--write" in args:
        print(write_lock(args[0]))
        return 0
    diff = check(args[0])
    print("\n".join(diff) if diff else "frozen: the suite is as its lock says")
    return 1 if diff else 0


if __name__ == "__main__":
    raise SystemExit(main())
