"""A receiver array (paper 003: the unit normals of the receivers, body frame FRD, receiver r at row r - 1)
as data: from the config (``receivers:`` a list of normals, the name of a known array, or a file), else from
the recording's header (``# receiver N: x y z`` lines, fusion.world). Used by the ``direction`` model and the
``orientation_geometric`` solver; the summary's ``info`` says which was used.

A file holds one receiver a line, ``x y z`` (numbered from 1 in order) or ``N: x y z`` / ``# receiver N: x y
z`` (numbered as written); blank lines and other ``#`` comments are skipped.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Callable, Union

import numpy as np

from fusion.api import ConfigError
from fusion.world import of_context

#: Receivers as a config gives them: None (the recording's header), an array's name or a file, or normals.
ReceiversSpec = Union[None, str, list[tuple[float, float, float]]]


def _truncated_icosahedron() -> np.ndarray:
    from fusion_plugins.simulators.arrival import truncated_icosahedron_normals

    return truncated_icosahedron_normals()


#: Known arrays by name: the paper's 32 receivers on a truncated icosahedron, in the project's numbering
NAMED: dict[str, Callable[[], np.ndarray]] = {"truncated_icosahedron": _truncated_icosahedron}
_NUMBERED = re.compile(r"^(?:#\s*)?(?:receiver\s+)?(\d+)\s*:\s*(.*)$")


def read_file(path: Path) -> np.ndarray:
    """Normals (k, 3) from a receiver file (module docstring); ConfigError naming path:line on a bad line."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"receivers: cannot read {path}: {exc}") from None
    numbered: dict[int, tuple[float, ...]] = {}
    for n, raw in enumerate(lines, 1):
        text = raw.strip()
        m = _NUMBERED.match(text)
        if not m and (not text or text.startswith("#")):
            continue
        number, values = (int(m.group(1)), m.group(2)) if m else (len(numbered) + 1, text)
        try:
            v = tuple(float(x) for x in values.replace(",", " ").split())
        except ValueError:
            v = ()
        if len(v) != 3 or not np.all(np.isfinite(v)) or not np.linalg.norm(v) > 0:
            raise ConfigError(f"{path}:{n}: a receiver is 3 finite numbers x y z, not all zero; got {text!r}")
        if number in numbered:
            raise ConfigError(f"{path}:{n}: receiver {number} given twice")
        numbered[number] = v
    if sorted(numbered) != list(range(1, len(numbered) + 1)):
        raise ConfigError(f"{path}: the receivers must be numbered 1..k without a gap; got {sorted(numbered)}")
    return np.array([numbered[i] for i in range(1, len(numbered) + 1)], float)


def resolve_receivers(spec: ReceiversSpec, context: Any, who: str) -> tuple[np.ndarray, dict[str, str]]:
    """(normals (k, 3) unit, info) of the array ``spec`` (module docstring) for component ``who``."""
    if spec is None:
        world = of_context(context)
        if world is not None and world.receivers is not None:
            normals, info = world.receivers.value, {"source": "recording header", "where": world.receivers.where}
        else:
            have = "no recording header known ahead (a stream)" if world is None else (
                f"the recording {world.path} lists no '# receiver N: x y z' lines")
            raise ConfigError(f"{who}: the receiver array is unknown: {have}; give receivers: the name of an array "
                              f"({', '.join(NAMED)}), a list of normals [x, y, z] (body frame, receiver 1 first) or a "
                              "file of them")
    elif isinstance(spec, str) and spec in NAMED:
        normals, info = NAMED[spec](), {"source": "config", "array": spec}
    elif isinstance(spec, str):
        path = Path(spec) if Path(spec).is_absolute() else Path(getattr(context, "base_dir", ".")) / spec
        if not path.is_file():
            raise ConfigError(f"{who}: receivers: {spec!r} is neither a known array ({', '.join(NAMED)}) nor a file")
        normals, info = read_file(path), {"source": "config", "file": str(path)}
    else:
        normals, info = np.asarray(spec, float), {"source": "config", "array": f"{len(spec)} normals"}
    if normals.ndim != 2 or normals.shape[1] != 3 or len(normals) < 4:
        raise ConfigError(f"{who}: receivers must be at least 4 normals of 3 values")
    norms = np.linalg.norm(normals, axis=1, keepdims=True)
    if not np.all(norms > 0):
        raise ConfigError(f"{who}: a receiver normal is zero")
    info["receivers"] = str(len(normals))
    return normals / norms, info
