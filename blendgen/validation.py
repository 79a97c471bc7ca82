"""Shared by every user-written YAML (jobs, twins): load a mapping, and turn pydantic's
errors into one line per field that names the field path and what was expected."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from blendgen.errors import UserError


def read_yaml_mapping(path: Path, what: str) -> Any:
    """The YAML document at `path`; UserError (naming the file and line) if it does not parse.
    The caller checks the type, so that an empty or list document gets its own message."""
    if not path.is_file():
        raise UserError(f"{what} file not found", where=str(path))
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        raise UserError(f"not valid YAML: {getattr(e, 'problem', e)}", where=where) from None


def _format_loc(loc) -> str:
    out = ""
    for p in loc:
        if str(p).startswith(("function-", "constrained-")):
            continue  # pydantic's validator wrappers, not fields
        out += f"[{p}]" if isinstance(p, int) else (("." if out else "") + str(p))
    return out or "(top level)"


def error_lines(e: ValidationError, unknown_hint: str = "") -> list[str]:
    lines = []
    for err in e.errors():
        loc = _format_loc(err["loc"])
        if err["type"] == "extra_forbidden":
            lines.append(f"{loc}: unknown key{unknown_hint}")
        elif err["type"] == "missing":
            lines.append(f"{loc}: required field is missing")
        else:
            got = err.get("input")
            got_s = "" if isinstance(got, dict) or got is None else f" (got {got!r})"
            lines.append(f"{loc}: {err['msg'].removeprefix('Value error, ')}{got_s}")
    return lines
