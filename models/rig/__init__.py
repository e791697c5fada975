"""Rigs from files: the schema (:mod:`models.rig.spec`) and the builder (:mod:`models.rig.model`).

A rig is picked by name (a file shipped in ``models/rigs/``) or by the path of a rig file,
everywhere a model is picked: scenarios, ``--model``, and the Python API::

    from models import get_model
    rig = get_model("rig3")                        # shipped
    rig = get_model("my_rigs/four_disc.toml")      # your own
"""

from __future__ import annotations

import os
from pathlib import Path

from models.checks import read_toml
from models.errors import ConfigError
from models.params import ParameterSet
from models.rig.model import RigModel
from models.rig.parse import parse_rig
from models.rig.spec import RigSpec

__all__ = ["RigModel", "RigSpec", "parse_rig", "load_rig", "get_model", "rig_key", "shipped_rigs", "RIGS_DIR",
           "load_params", "published"]

RIGS_DIR = Path(__file__).resolve().parent.parent / "rigs"
_CACHE: dict[str, RigModel] = {}


def shipped_rigs() -> tuple[str, ...]:
    """Names of the rig files shipped with the package (``models/rigs/*.toml``)."""
    return tuple(sorted(p.stem for p in RIGS_DIR.glob("*.toml")))


def _resolve(name_or_path: str) -> Path:
    text = str(name_or_path)
    shipped = RIGS_DIR / f"{text}.toml"
    if "/" not in text and "\\" not in text and not text.endswith(".toml"):
        if shipped.exists():
            return shipped
        raise ConfigError(f"model must be a shipped rig ({', '.join(shipped_rigs())}) or a rig file path, "
                          f"got {text!r}")
    path = Path(text).expanduser()
    if not path.exists():
        raise ConfigError(f"{text}: rig file not found")
    return path.resolve()


def load_rig(path: str | os.PathLike) -> RigModel:
    """Read, validate and build a rig file (no cache)."""
    path = Path(path)
    spec = parse_rig(read_toml(path, "rig file"), str(path))
    key = path.stem if path.resolve().parent == RIGS_DIR else str(path.resolve())
    return RigModel(spec, key)


def get_model(model) -> RigModel:
    """A rig model from a shipped name (``"rig3"``), a rig-file path, or a model (returned as is).

    Built models are cached by their resolved file and its modification time.
    """
    if isinstance(model, RigModel):
        return model
    if not isinstance(model, (str, os.PathLike)):
        raise ConfigError(f"model must be a rig name, a rig file path or a RigModel, got {type(model).__name__}")
    path = _resolve(str(model))
    key = f"{path}:{path.stat().st_mtime_ns}"
    if key not in _CACHE:
        _CACHE[key] = load_rig(path)
    return _CACHE[key]


def rig_key(model) -> str:
    """How a model is referred to in files: its shipped name, else its file's absolute path."""
    return get_model(model).key


def published(model) -> ParameterSet:
    """The published parameter set of a rig (a shipped name such as ``"rig3"``, or a rig-file path)."""
    return get_model(model).published()


def load_params(path: str | os.PathLike, model=None) -> ParameterSet:
    """Load a parameter TOML file.

    ``model`` (a rig name, path or model), if given, must match the file's ``model`` key; the
    file's ``model`` names a shipped rig or a rig file (relative paths are taken from the
    parameter file's folder).
    """
    path = Path(path)
    data = read_toml(path, "parameter file")
    name = data.get("model")
    if name is None and model is None:
        raise ConfigError(f"{path}: missing field 'model' (a rig name or rig file)")
    if name is not None and not isinstance(name, str):
        raise ConfigError(f"{path}: model must be a rig name or path, got {name!r}")
    want = get_model(model) if model is not None else None
    if name is None:
        m = want
    else:
        cand = Path(name)
        if name.endswith(".toml") and not cand.is_absolute() and (path.parent / cand).exists():
            name = str(path.parent / cand)
        try:
            m = get_model(name)
        except ConfigError as exc:
            raise ConfigError(f"{path}: model: {exc}") from None
    if want is not None and rig_key(m) != rig_key(want):
        raise ConfigError(f"{path}: model must be {want.name!r} here, got {m.name!r}")
    return m.published().from_mapping(data, where=str(path))    # every message opens with the path
