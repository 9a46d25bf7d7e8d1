"""The run summary as JSON (``--summary-json PATH``), DESIGN.md "Outputs".

``write_summary_json(path, summary)`` writes the summary dict assembled by ``fusion run``
(``{"config", "filter", "input", "duration_s", "wall_s", "steps", "us_per_predict", "us_per_update",
"sensors", "errors", "consistency"}``). numpy scalars and arrays become plain numbers and lists;
non-finite numbers become ``null`` (strict JSON). The file is written to a temporary name beside it and
renamed, so a reader never sees half a summary. ``-`` writes to stdout.
"""
from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np

__all__ = ["write_summary_json", "to_jsonable"]


def to_jsonable(obj: Any) -> Any:
    """``obj`` with numpy types, tuples and non-finite floats turned into strict-JSON values."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return obj


def write_summary_json(path: str | os.PathLike, summary: dict) -> None:
    """Write ``summary`` as indented JSON to ``path`` (atomically; ``-`` for stdout)."""
    from fusion.outputs import write_text

    text = json.dumps(to_jsonable(summary), indent=2, allow_nan=False) + "\n"
    write_text(path, text, what="summary")
