"""YAML loading that remembers where each value came from, so errors can name the file and line.

The one locator (:meth:`LocatedYAML.line_of`, :meth:`LocatedYAML.where`) and the one pydantic error
formatter (:func:`pydantic_errors`) of the project: system configs (fusion.config) and scenarios
(fusion.simulate) both report ``file:line: field.path: problem``."""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Sequence

import yaml

from fusion.api import ConfigError


#: Deepest nesting of a YAML document, counted after alias expansion: a system config nests ~5 levels;
#: the bound keeps the recursive composer (and pydantic after it) far from Python's recursion limit.
MAX_DEPTH = 64
#: Most values a document may expand to through aliases ("billion laughs": 9 aliases of 9 aliases of ...
#: is 10 lines of YAML and 387 million values for pydantic to walk).
MAX_VALUES = 100_000
_MERGE = "tag:yaml.org,2002:merge"


class _Loader(yaml.SafeLoader):
    """SafeLoader that refuses, with the line, a duplicate key, nesting deeper than MAX_DEPTH, a recursive
    alias and a document expanding to more than MAX_VALUES values."""

    def __init__(self, stream: str):
        super().__init__(stream)
        self._depth = 0
        self._nodes = 0

    def compose_node(self, parent, index):  # type: ignore[override]
        self._depth += 1
        self._nodes += 1
        try:
            if self._nodes > MAX_VALUES:   # refused as it is read, before the rest is composed
                raise yaml.composer.ComposerError(None, None, f"holds more than {MAX_VALUES} values (a config has "
                                                  "a few hundred)", self.peek_event().start_mark)
            if self._depth > MAX_DEPTH:
                raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_DEPTH} levels",
                                                  self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def compose_mapping_node(self, anchor):  # type: ignore[override]
        node = super().compose_mapping_node(anchor)
        seen: dict[Any, int] = {}
        for key, _ in node.value:
            if not isinstance(key, yaml.ScalarNode) or key.tag == _MERGE:
                continue
            try:
                k = (type(v := self.construct_object(key)), v)
                hash(k)
            except (yaml.YAMLError, TypeError):
                k = (key.tag, key.value)
            if k in seen:
                raise yaml.composer.ComposerError(
                    None, None, f"duplicate key {key.value!r} (first at line {seen[k]}; a later one would "
                    "silently replace it)", key.start_mark)
            seen[k] = key.start_mark.line + 1
        return node


def _check_expansion(root: yaml.Node) -> None:
    """ComposerError when aliases make the document recursive, deeper than MAX_DEPTH or larger than
    MAX_VALUES values once expanded (each node is visited once: aliases share their node)."""
    size: dict[int, tuple[int, int]] = {}
    active: set[int] = set()

    def walk(node: yaml.Node, level: int) -> tuple[int, int]:
        if id(node) in size:
            return size[id(node)]
        if id(node) in active:
            raise yaml.composer.ComposerError(None, None, "recursive alias (a value that contains itself)",
                                              node.start_mark)
        if level > MAX_DEPTH:
            raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_DEPTH} levels (through "
                                              "aliases)", node.start_mark)
        active.add(id(node))
        n, depth = 1, 1
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [c for kv in node.value for c in kv]
        else:
            children = []
        for child in children:
            cn, cd = walk(child, level + 1)
            n, depth = n + cn, max(depth, cd + 1)
            if n > MAX_VALUES:
                raise yaml.composer.ComposerError(None, None, f"expands to more than {MAX_VALUES} values "
                                                  "(aliases of aliases?)", node.start_mark)
        if depth > MAX_DEPTH:
            raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_DEPTH} levels (through "
                                              "aliases)", node.start_mark)
        active.discard(id(node))
        size[id(node)] = (n, depth)
        return n, depth

    walk(root, 1)


def parse_yaml(text: str) -> tuple[Any, yaml.Node | None]:
    """(data, root node) of one YAML document; yaml.YAMLError (with its mark) for a syntax error, a
    duplicate key, nesting deeper than MAX_DEPTH, a recursive alias or an expansion over MAX_VALUES."""
    loader = _Loader(text)
    try:
        root = loader.get_single_node()
        if root is None:
            return None, None
        _check_expansion(root)
        try:
            return loader.construct_document(root), root
        except ValueError as exc:   # Python's limit on int digits (4300), a date out of range, ...
            raise yaml.constructor.ConstructorError(None, None, f"a value cannot be read ({exc})",
                                                    _longest_scalar(root)) from None
    finally:
        loader.dispose()


def _longest_scalar(root: yaml.Node):
    """The start mark of the longest scalar under ``root`` (where an unreadable value most likely is)."""
    best, mark, stack = -1, None, [root]
    while stack:
        node = stack.pop()
        if isinstance(node, yaml.ScalarNode):
            if len(node.value) > best:
                best, mark = len(node.value), node.start_mark
        elif isinstance(node, yaml.MappingNode):
            stack.extend(v for kv in node.value for v in kv)
        elif isinstance(node, yaml.SequenceNode):
            stack.extend(node.value)
    return mark


def yaml_problem(exc: yaml.YAMLError) -> tuple[int | None, str]:
    """(1-based line or None, what is wrong) of a YAML error, for one-line messages."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None) or str(exc).replace("\n", " ")
    return (mark.line + 1 if mark is not None else None), problem


class LocatedYAML:
    """A parsed YAML document plus the node tree, to map a field path to its line number."""

    def __init__(self, path: Path | str, data: Any, root: yaml.Node | None):
        self.path = path
        self.data = data
        self.root = root

    @classmethod
    def from_text(cls, text: str, where: str = "<yaml>") -> "LocatedYAML":
        """The document of YAML ``text`` (``where``: its file, for messages); ConfigError ``where:line:
        invalid YAML: ...`` for a syntax error, a duplicate key, an alias bomb (fusion.yamlsource limits)."""
        try:
            data, root = parse_yaml(text)
        except yaml.YAMLError as exc:
            line, problem = yaml_problem(exc)
            raise ConfigError(f"{where}{f':{line}' if line else ''}: invalid YAML: {problem}") from None
        return cls(where, data, root)

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

    def error(self, msg: str) -> ConfigError:
        """ConfigError of a message about this document: one that starts with a field path (``a.b.2.c:
        ...``) gets the file and that field's line (``file:line: a.b.2.c: ...``), another the file; one
        that already names the file is kept."""
        where = str(self.path)
        if msg.startswith(where):
            return ConfigError(msg)
        head, sep, rest = msg.partition(": ")
        if sep and head and " " not in head:
            loc = [int(x) if x.isdigit() else x for x in head.split(".")]
            return ConfigError(f"{self.where(loc)}: {rest}")
        return ConfigError(f"{where}: {msg}")


#: Largest YAML file read (bytes): a config or scenario is a few kB (the largest shipped one ~10 kB; a 48 x 48
#: covariance written out ~30 kB). PyYAML's pure-Python composer costs ~3 s and ~150 MB a MB of plain
#: numbers, so a wrong path (a log, a table, a disk image) is refused by its size before it is parsed.
MAX_YAML_BYTES = 256 * 1024


def read_yaml_text(path: str | Path, what: str = "file") -> str:
    """The UTF-8 text of a YAML file (a config, scenario or mapping: ``what`` names it in messages).
    ConfigError, naming the path, for a missing file, a directory, anything that is not a regular file (a
    device such as /dev/zero, a FIFO: reading it would never end or fill the memory), a file over
    MAX_YAML_BYTES, or text that is not UTF-8."""
    import os
    import stat as stat_

    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # a FIFO without a writer: no hang
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such {what}") from None
    except IsADirectoryError:
        raise ConfigError(f"{p}: is a directory, expected a YAML file") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the {what}: {exc.strerror or exc}") from None
    mode = os.fstat(fd).st_mode
    if stat_.S_ISDIR(mode):          # os.open opens a folder; os.fdopen would then fail with "Is a directory: 3"
        os.close(fd)
        raise ConfigError(f"{p}: is a folder, not a YAML {what}")
    with os.fdopen(fd, "rb") as fh:
        if not stat_.S_ISREG(mode):
            kind = ("a character device" if stat_.S_ISCHR(mode) else "a FIFO" if stat_.S_ISFIFO(mode)
                    else "a block device" if stat_.S_ISBLK(mode) else "a socket" if stat_.S_ISSOCK(mode)
                    else "not a regular file")
            raise ConfigError(f"{p}: {kind}, not a readable regular file; give a YAML {what}")
        size = os.fstat(fh.fileno()).st_size
        data = fh.read(MAX_YAML_BYTES + 1)
    if len(data) > MAX_YAML_BYTES:
        raise ConfigError(f"{p}: larger than {_bytes(MAX_YAML_BYTES)} ({_bytes(max(size, len(data)))}), the most a "
                          f"YAML {what} may be (a config is a few kB; a recording, a table or a binary file given "
                          "in its place?)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def _bytes(n: int) -> str:
    """A byte count for messages: ``812 bytes``, ``256 KiB``, ``1.1 MiB``."""
    return f"{n} bytes" if n < 1024 else f"{n / 1024:.4g} KiB" if n < 1024 ** 2 else f"{n / 1024 ** 2:.3g} MiB"


def load_yaml(path: str | Path, what: str = "file") -> LocatedYAML:
    """Read a YAML file (through ``read_yaml_text``: a regular file of at most MAX_YAML_BYTES); ConfigError
    with file and line for a missing or unreadable file or a syntax error."""
    p = Path(path)
    text = read_yaml_text(p, what)
    doc = LocatedYAML.from_text(text, str(p))
    if not isinstance(doc.data, dict):
        raise ConfigError(f"{p}: expected a mapping of keys at the top level, got {type(doc.data).__name__}")
    doc.path = p
    return doc


_TYPE_TAG = re.compile(r"^(float|int|str|bool|none|list|dict|tuple|set|literal|union|nullable)(\[.*\])?$|^function-")


def _field_path(data: Any, loc: Sequence[Any]) -> list[Any]:
    """The YAML path of a pydantic error location: without the names pydantic gives the members of a
    union (``float``, ``list[float]``) and its validators (``function-after[...]``), unless the data has
    such a key there."""
    out: list[Any] = []
    tagged = None   # the mapping whose union tag was skipped (once per level)
    for part in loc:
        if isinstance(part, str) and _TYPE_TAG.match(part) and not (isinstance(data, dict) and part in data):
            continue
        if isinstance(data, dict) and data is not tagged and isinstance(part, str) and data.get("type") == part:
            tagged = data  # the tag of a union discriminated by its ``type`` key (a scenario's trajectory)
            continue
        out.append(part)
        if isinstance(data, dict):
            data = data.get(part)
        elif isinstance(data, list) and isinstance(part, int) and 0 <= part < len(data):
            data = data[part]
        else:
            data = None
    return out


def _shape_mismatch(err: dict) -> bool:
    """An error that only says the value has another type than one member of a union (``float_type``,
    ``list_type``, ``float_parsing``): less telling than a member whose shape fits and whose value fails."""
    return err["type"].endswith(("_type", "_parsing")) and err["type"] != "literal_error"


def pydantic_errors(doc: LocatedYAML | None, exc: Any, prefix: Sequence[Any] = (), data: Any = None) -> ConfigError:
    """Turn a pydantic ValidationError into one ConfigError naming file:line (when ``doc`` is given; else
    the field path only, for values from the command line), field path and problem (the most telling
    error first: a value of the right shape that fails a bound before a type mismatch with another member
    of a union). ``data``: the validated input when there is no doc."""
    lines = []
    if doc is not None:
        data = doc.data
    else:
        prefix, data = (), data
    for p in prefix:
        data = data.get(p) if isinstance(data, dict) else (data[p] if isinstance(data, list) and isinstance(p, int)
                                                             and 0 <= p < len(data) else None)
    errors = sorted(exc.errors(), key=_shape_mismatch)  # stable: document order otherwise
    telling = [tuple(_field_path(data, e["loc"])) for e in errors if not _shape_mismatch(e)]
    for err in errors:
        path = _field_path(data, err["loc"])
        if _shape_mismatch(err) and any(t[:len(path)] == tuple(path) for t in telling):
            continue  # another member of the union fits this value's shape and says what is wrong
        loc = [*prefix, *path]
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        where = doc.where(loc) if doc is not None else ".".join(map(str, loc))
        line = f"{where}: {msg}" if where else msg   # a model-wide check has no field path
        if line not in lines:
            lines.append(line)
    more = f" (and {len(lines) - 1} more: " + "; ".join(lines[1:4]) + ")" if len(lines) > 1 else ""
    return ConfigError(lines[0] + more)
