"""YAML loading that remembers where each value came from, so errors can name the file and line."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import yaml

from fusion.api import ConfigError


class LocatedYAML:
    """A parsed YAML document plus the node tree, to map a field path to its line number."""

    def __init__(self, path: Path, data: Any, root: yaml.Node | None):
        self.path = path
        self.data = data
        self.root = root

    def line_of(self, loc: Sequence[Any]) -> int | None:
        """1-based line of the value at ``loc`` (keys and list indices); the deepest existing node."""
        node = self.root
        line = node.start_mark.line + 1 if node is not None else None
        for key in loc:
            if isinstance(node, yaml.MappingNode):
                for k, v in node.value:
                    if k.value == str(key):
                        node = v
                        line = k.start_mark.line + 1
                        break
                else:
                    return line
            elif isinstance(node, yaml.SequenceNode) and isinstance(key, int) and key < len(node.value):
                node = node.value[key]
                line = node.start_mark.line + 1
            else:
                return line
        return line

    def where(self, loc: Sequence[Any]) -> str:
        """``file:line: field.path`` for messages."""
        line = self.line_of(loc)
        dotted = ".".join(str(p) for p in loc)
        at = f"{self.path}:{line}" if line else str(self.path)
        return f"{at}: {dotted}" if dotted else at


def load_yaml(path: str | Path) -> LocatedYAML:
    """Read a YAML file; ConfigError with file and line for a missing file or a syntax error."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{p}: is a directory, expected a YAML file") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(f"{p}{line}: invalid YAML: {problem}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a mapping of keys at the top level, got {type(data).__name__}")
    return LocatedYAML(p, data, root)


def pydantic_errors(doc: LocatedYAML, exc: Any, prefix: Sequence[Any] = ()) -> ConfigError:
    """Turn a pydantic ValidationError into one ConfigError naming file:line, field path and problem."""
    lines = []
    for err in exc.errors():
        loc = [*prefix, *[p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-"))]]
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        lines.append(f"{doc.where(loc)}: {msg}")
    more = f" (and {len(lines) - 1} more: " + "; ".join(lines[1:4]) + ")" if len(lines) > 1 else ""
    return ConfigError(lines[0] + more)
