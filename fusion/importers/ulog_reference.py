"""The onboard estimator of a PX4 ULog as ``reference`` lines, for the ``ulog`` importer:
``vehicle_local_position`` (NED from the EKF's local origin, by its validity flags) with the attitude of
``vehicle_attitude`` slerped to its times, the EKF's origin on the globe, and the initial attitude."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from fusion.api import ImportRequest, InputError, Stream
from fusion.importers.common import in_span, make_stream, slerp_to


def _cols(d, names: list[str]) -> np.ndarray:
    missing = [n for n in names if n not in d.data]
    if missing:
        have = ", ".join(k for k in d.data if k != "timestamp")
        raise InputError(f"topic {d.name}: no field {missing[0]!r} in this log's layout (it has: {have[:300]})")
    return np.column_stack([np.asarray(d.data[n], float) for n in names])


_FLAGS = ("xy_valid", "z_valid", "v_xy_valid", "v_z_valid", "xy_global", "z_global")


def _named(idx: np.ndarray, t: np.ndarray, what: list[str], limit: int = 3) -> str:
    """``sample 324 (t 3.405 s): xy_valid=-44`` for the first ``limit`` of the samples ``idx``."""
    out = "; ".join(f"sample {int(i)} (t {t[i]:.3f} s){': ' + what[i] if what[i] else ''}" for i in idx[:limit])
    return out + (f"; and {len(idx) - limit} more" if len(idx) > limit else "")


def _corrupt_flags(data: dict, n: int) -> tuple[np.ndarray, list[str]]:
    """Samples whose validity flags are not 0/1 (a ULog bool is one byte, 0 or 1: anything else is damaged
    data), and per sample the flags that say so."""
    bad = np.zeros(n, bool)
    said = [""] * n
    for flag in _FLAGS:
        if flag not in data:
            continue
        raw = np.asarray(data[flag]).astype(np.int64)
        wrong = (raw != 0) & (raw != 1)
        for i in np.flatnonzero(wrong).tolist():
            said[i] += (", " if said[i] else "") + f"{flag}={int(raw[i])}"
        bad |= wrong
    return bad, said


def _valid_attitude(att, tcol, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(times, q) of the ``vehicle_attitude`` samples whose quaternion is finite and of unit norm (a
    float32 quaternion of PX4 is unit to ~1e-7: one off by more is damaged data, skipped with a note)."""
    t = tcol(att)
    q = _cols(att, [f"q[{i}]" for i in range(4)])
    with np.errstate(invalid="ignore", over="ignore"):
        ok = np.all(np.isfinite(q), axis=1) & (np.abs(np.linalg.norm(q, axis=1) - 1.0) < 1e-3)
    if not ok.all():
        bad = np.flatnonzero(~ok)
        notes.append(f"reference: {len(bad)} vehicle_attitude sample(s) with a quaternion that is not of unit norm "
                     f"(corrupt) skipped: {_named(bad, t, [''] * len(t))}")
    return t[ok], q[ok]


def _choose(valid: dict[str, np.ndarray], sizes: dict[str, int], extra: int, base: np.ndarray) -> list[str]:
    """The groups of elements to write: of those ever valid, the set that writes the most values
    (elements x samples at which all of them are valid; ``extra`` elements, the attitude, ride along with
    every sample of ``base``, the usable samples in the span). Ties go to the larger set. The log format has one column set a stream, so an element
    valid only late either shortens the whole reference or is left out, whichever loses less."""
    import itertools

    names = [g for g in valid if valid[g].any()]
    best, best_score = [], (-1, -1)
    for r in range(len(names), -1, -1):
        for combo in itertools.combinations(names, r):
            keep = base.copy()
            for g in combo:
                keep &= valid[g]
            width = sum(sizes[g] for g in combo) + extra
            score = (width * int(keep.sum()) if width else 0, width)
            if score > best_score:
                best, best_score = list(combo), score
    return best


def _reference(lpos, att, tcol, request: ImportRequest, notes: list[str]) -> tuple[Stream | None, Any, Any]:
    """Reference stream at the local-position times (attitude slerped to them), or attitude only; the
    EKF's origin on the globe (or None); the initial attitude (t, q) or None.

    A ``vehicle_local_position`` sample whose validity flags are not 0/1 is corrupt and skipped (named in a
    note). Of the element groups the EKF flags valid (``px py`` by xy_valid, ``pz`` z_valid, ``vx vy``
    v_xy_valid, ``vz`` v_z_valid), the set that writes the most values is written (see ``_choose``; a
    group left out is named with the time it becomes valid), at the samples where all of them are valid.
    The initial attitude is the first valid attitude, at the first reference time or the first attitude
    sample, whichever is earlier, in the span: never moved by when the position becomes valid."""
    groups = (("px py", ["x", "y"], "xy_valid"), ("pz", ["z"], "z_valid"),
              ("vx vy", ["vx", "vy"], "v_xy_valid"), ("vz", ["vz"], "v_z_valid"))
    origin = None
    meta = {"frame": "NED from the EKF's local origin; q body FRD to NED, [w x y z]",
            "source": "PX4 EKF: " + " + ".join(d.name for d in (lpos, att) if d is not None)}
    t_att = q_att = None
    if att is not None:
        t_att, q_att = _valid_attitude(att, tcol, notes)
        if len(t_att) == 0:
            t_att = q_att = None
    initial = None
    if t_att is not None:
        in_att = in_span(t_att, request)
        if in_att.any():
            initial = (float(t_att[in_att][0]), q_att[in_att][0])
    if lpos is not None:
        data = lpos.data
        t = tcol(lpos)
        n = len(t)
        corrupt, said = _corrupt_flags(data, n)
        if corrupt.any():
            idx = np.flatnonzero(corrupt)
            notes.append(f"reference: {len(idx)} of {n} vehicle_local_position sample(s) skipped as corrupt "
                         f"(a validity flag neither 0 nor 1): {_named(idx, t, said)}")
        ok = ~corrupt
        span = in_span(t, request)   # the column set is chosen by the samples to be written
        valid = {}
        for names, src, flag in groups:
            v = (np.asarray(data[flag]) == 1) if flag in data else np.ones(n, bool)
            valid[names] = v & ok & span
        sizes = {g: len(g.split()) for g in valid}
        base = ok & span
        m = int(base.sum())
        chosen = _choose(valid, sizes, 4 if t_att is not None else 0, base)
        fields: list[str] = []
        cols: list[np.ndarray] = []
        keep = base.copy()
        for names, src, flag in groups:
            if not valid[names].any():
                notes.append(f"reference: the EKF never flags {flag}: no {names}")
                continue
            if names not in chosen:
                first = np.flatnonzero(valid[names])[0]
                since = math.floor(t[first] * 1000.0) / 1000.0   # a --start that includes it
                notes.append(f"reference: the EKF flags {flag} only in {int(valid[names].sum())} of {m} sample(s) "
                             f"(from t {since:.3f} s): no {names}, so that the other elements are written over "
                             f"the whole span (import with --start {since:.3f} for all of them)")
                continue
            fields += names.split()
            cols += [np.asarray(data[c], float) for c in src]
            keep &= valid[names]
        if fields:
            dropped = int(np.sum(base & ~keep))
            if dropped:
                notes.append(f"reference: {dropped} of {m} sample(s) at which not all of {' '.join(fields)} are "
                             "valid dropped")
            if t_att is not None:
                q = slerp_to(t_att, q_att, t)
                fields += ["qw", "qx", "qy", "qz"]
                cols += [q[:, i] for i in range(4)]
            if "xy_global" in data and "ref_lat" in data:
                g = np.flatnonzero((np.asarray(data["xy_global"]) == 1) & keep)
                if g.size:
                    i = g[0]
                    origin = (float(data["ref_lat"][i]), float(data["ref_lon"][i]), float(data["ref_alt"][i]))
            v = np.column_stack(cols)[keep]
            s = make_stream("reference", tuple(fields), t[keep], v, request, meta=meta, notes=notes)
            if initial is not None and len(s) and s.t[0] < initial[0]:   # held back to the first reference time
                initial = (float(s.t[0]), slerp_to(t_att, q_att, s.t[:1])[0])
            return s, origin, initial
    if t_att is None:
        return None, None, None
    return (make_stream("reference", ("qw", "qx", "qy", "qz"), t_att, q_att, request, meta=meta, notes=notes),
            None, initial)
