"""Shared by every user-written YAML (jobs, twins): load a mapping, and turn pydantic's
errors into one line per field that names the field path and what was expected."""

from __future__ import annotations

import re
import reprlib
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from blendgen.errors import UserError


MAX_YAML_BYTES = 1 << 20   # a job, twin or calib file is a few KB; 1 MB is a wrong file
MAX_YAML_VALUES = 100_000  # values after expanding anchors/aliases (a "billion laughs" bomb)
# What an error message may quote of a user's value: bounded, whatever the value's size.
_QUOTE = reprlib.Repr()  # Python 3.11: limits are attributes, not constructor arguments
_QUOTE.maxlevel, _QUOTE.maxstring, _QUOTE.maxother, _QUOTE.maxlong = 2, 60, 60, 40
_QUOTE.maxtuple = _QUOTE.maxlist = _QUOTE.maxdict = _QUOTE.maxset = 4
quote = _QUOTE.repr


class StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys (PyYAML keeps the last one silently) and reads
    YAML 1.2 floats such as `5e-05` as numbers (YAML 1.1 needs a dot: `5.0e-05`)."""

    MAX_DEPTH = 50  # a job nests 3 levels; PyYAML itself would recurse until RecursionError

    def compose_node(self, parent, index):
        self._depth = getattr(self, "_depth", 0) + 1
        try:
            if self._depth > self.MAX_DEPTH:
                raise yaml.composer.ComposerError(None, None, f"nested more than {self.MAX_DEPTH} "
                                                  "levels deep", self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node, deep=False):
        seen: dict = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if isinstance(key, (str, int, float, bool)) and key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {quote(key)} (first on line {seen[key] + 1})",
                    key_node.start_mark)
            if isinstance(key, (str, int, float, bool)):
                seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)


StrictLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789"))


def _count_values(obj: Any, limit: int) -> int:
    """Values in `obj` counting shared (aliased) ones each time they appear, up to `limit`."""
    n, stack = 0, [obj]
    while stack and n <= limit:
        o = stack.pop()
        n += 1
        if isinstance(o, dict):
            stack.extend(o.keys())
            stack.extend(o.values())
        elif isinstance(o, (list, tuple)):
            stack.extend(o)
    return n


def load_yaml_text(path: Path, what: str) -> Any:
    """Parse the YAML file at `path` safely: size-capped, UTF-8, no duplicate keys, no alias
    bombs. UserError naming the file (and line) for anything else than a sane document."""
    try:
        size = path.stat().st_size
        if size > MAX_YAML_BYTES:
            raise UserError(f"{what} file is {size / 2**20:.1f} MB; a {what} file is expected to be "
                            f"under {MAX_YAML_BYTES // 2**20} MB (wrong file?)", where=str(path))
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise UserError(f"not a text (UTF-8) file: byte {e.start} is {e.object[e.start]:#04x}; "
                        f"expected a YAML {what} file", where=str(path)) from None
    except OSError as e:
        raise UserError(f"cannot read the {what} file: {e.strerror}", where=str(path)) from None
    try:
        data = yaml.load(text, Loader=StrictLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        raise UserError(f"not valid YAML: {getattr(e, 'problem', None) or e}", where=where) from None
    if _count_values(data, MAX_YAML_VALUES) > MAX_YAML_VALUES:
        raise UserError(f"the YAML expands to more than {MAX_YAML_VALUES} values (anchors and "
                        f"aliases repeated into a huge document?); expected a small {what} file",
                        where=str(path))
    return data


def read_yaml_mapping(path: Path, what: str) -> Any:
    """The YAML document at `path`; UserError (naming the file and line) if it does not parse.
    The caller checks the type, so that an empty or list document gets its own message."""
    if not path.is_file():
        raise UserError(f"{what} file not found", where=str(path))
    return load_yaml_text(path, what)


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
            got_s = "" if isinstance(got, dict) or got is None else f" (got {quote(got)})"
            lines.append(f"{loc}: {err['msg'].removeprefix('Value error, ')}{got_s}")
    return lines
