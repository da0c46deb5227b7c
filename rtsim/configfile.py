"""Loading TOML configuration files into validated pydantic models, with one-line errors that name
the file, the key, the offending value and what is allowed."""
from __future__ import annotations

import tomllib
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from rtsim.errors import ConfigError

M = TypeVar("M", bound=BaseModel)


class Strict(BaseModel):
    """Base of every config section: unknown keys are errors (a typo must not pass silently)."""
    model_config = ConfigDict(extra="forbid", frozen=True)


def _describe(err: dict) -> str:
    loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
    msg = err["msg"]
    ctx = err.get("ctx") or {}
    if err["type"] == "missing":
        return f"missing key '{loc}'"
    if err["type"] == "extra_forbidden":
        return f"unknown key '{loc}'"
    value = err.get("input")
    bounds = ", ".join(f"{k} {v}" for k, v in ctx.items() if k in ("gt", "ge", "lt", "le"))
    allowed = f" (allowed: {bounds})" if bounds else ""
    return f"'{loc}' = {value!r}: {msg}{allowed}"


def validate(model: type[M], data: dict, source: str) -> M:
    """Validate `data` against `model`; ConfigError naming `source` and every bad key otherwise."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(_describe(e) for e in exc.errors())
        raise ConfigError(f"{source}: {problems}") from None


def load_toml(path: str | Path) -> dict:
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def load(model: type[M], path: str | Path) -> M:
    return validate(model, load_toml(path), str(path))
