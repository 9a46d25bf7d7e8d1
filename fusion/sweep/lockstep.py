"""The recordings of a variant's seeds as arrays, message by message in lockstep: what the batched engine
reads, built without the text round-trip where that gives the same numbers.

A trial's recording is ``fusion.simulate`` text, parsed by ``fusion.logformat`` and turned into
observations by each sensor's decoder and measurement model. :func:`from_simulation` gets the same
messages from ``fusion.simulate.engine.simulate_parts`` (the data the text is formatted from): the
trajectory built once for all seeds (it does not depend on the seed), each seed's sensor noise from its
own generators as ``fusion simulate`` draws it, times and values rounded exactly as the text's fixed
decimals round them (:func:`round_text`), the messages merged in the text's order (time, then stream) and
every distinct line shape checked against the real parser. Observations of a ``range`` model read by the
``line`` decoder are vectorised (fusion.sweep.observe, checked against the model's own ``observe`` for
each beacon pattern); any other model is observed message by message. Whatever this fast path does not
cover (a value that is neither a number nor a label, mixed columns, non-finite numbers) is rendered and
parsed as text (:func:`from_texts`), the engine's original path; both give identical arrays
(tests/sweep/test_lockstep.py).
"""
from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from fusion.api import MalformedMessage, Message

__all__ = ["Lockstep", "NotLockstep", "round_text", "from_simulation", "from_texts"]


class NotLockstep(Exception):
    """The recordings of the seeds differ in their timing or content structure."""


class _Slow(Exception):
    """The fast path does not cover this recording: render and parse the text."""


def round_text(a: np.ndarray, decimals: int) -> np.ndarray:
    """``float(f"{v:.{decimals}f}")`` for every v of ``a``, vectorised and exact: the decimal rounding
    ``k = rint(v 10^d)`` is recomputed by Python's formatting wherever the product's own rounding could
    move it across a half (or is too large for an integer double), and ``k / 10^d`` is then the correctly
    rounded double of the decimal text, as ``float()`` of it is."""
    a = np.asarray(a, dtype=float)
    if decimals > 22:                                # 10^d no longer exact: format everything
        return _by_text(a, decimals, np.ones(a.shape, bool))
    scale = 10.0 ** decimals
    with np.errstate(over="ignore", invalid="ignore"):
        s = a * scale
        k = np.rint(s)
        risky = ~(np.abs(s) < 2.0 ** 51) | (np.abs(np.abs(s - k) - 0.5) <= 4.0 * np.spacing(np.abs(s)) + 1e-300)
    out = k / scale
    out = np.where(k == 0.0, np.copysign(0.0, a), out)   # "-0.00" parses to -0.0
    if risky.any():
        out = _by_text(a, decimals, risky, out)
    return out


def _by_text(a: np.ndarray, d: int, mask: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    out = np.empty(a.shape) if out is None else out
    flat, src = out.reshape(-1), a.reshape(-1)
    for i in np.flatnonzero(mask.reshape(-1)).tolist():
        flat[i] = float(f"{float(src[i]):.{d}f}")
    return out


@dataclass
class Lockstep:
    """The N recordings of one variant, message by message (the same sensors, times and line shapes).

    ``events``: in recording order, ``("truth", j)`` (truth sample j) or ``("meas", sensor, t, model, z)``
    with the bound measurement model of the message and the N observations ``z`` (N, m). ``headers``: each
    recording's parsed header. ``truth_names``; ``truth_t`` (T,) s and ``truth_v`` (N, T, m) as parsed;
    ``truth_idx`` (T,) their indices in ``events``; ``truth_ok``: every truth message is one the truth
    window takes (len(names) finite numbers)."""

    headers: list[Any]
    events: list[tuple]
    truth_names: tuple[str, ...] | None
    truth_t: np.ndarray
    truth_v: np.ndarray
    truth_idx: np.ndarray
    truth_lines: list[int] = field(default_factory=list)
    truth_ok: bool = True
    source: str = "simulation"

    @property
    def N(self) -> int:
        return len(self.headers)

    def truth_message(self, i: int, j: int) -> Message:
        """Truth sample j of recording i as the parser's Message."""
        return Message(float(self.truth_t[j]), "truth", tuple(self.truth_v[i, j].tolist()),
                       self.truth_lines[j] if self.truth_lines else None)


# --------------------------------------------------------------------------- the text path
def from_texts(system: Any, texts: Sequence[Sequence[str]]) -> Lockstep:
    """The lockstep messages of recordings given as lines: parsed, decoded and observed one by one
    (NotLockstep when they differ in structure, or on a malformed line or message)."""
    from fusion.logformat import ParsedStream, iter_messages

    per: list[list[tuple]] = []
    headers = []
    for lines in texts:
        parsed = ParsedStream()
        out: list[tuple] = []
        for item in iter_messages(lines, parsed):
            if isinstance(item, MalformedMessage):
                raise NotLockstep("a malformed line")
            if item.sensor in ("truth", "reference"):
                out.append((item.sensor, item))
                continue
            sensor = system.sensors.get(item.sensor)
            if sensor is None:
                raise NotLockstep(f"a sensor not in the config ({item.sensor})")
            try:
                dec = sensor.decoder.decode(item)
                obs = None if dec is None else sensor.model.observe(dec)
            except MalformedMessage:
                raise NotLockstep("a malformed message") from None
            if obs is None:
                continue
            if obs.R is not None:
                raise NotLockstep("an observation with its own R")
            out.append(("meas", sensor.name, obs))
        per.append(out)
        headers.append(parsed.header)
    sig = [_signature(it) for it in per[0]]
    for items in per[1:]:
        if len(items) != len(sig) or any(_signature(it) != s for it, s in zip(items, sig)):
            raise NotLockstep("the seeds' recordings differ in timing or content")
    names = headers[0].fields.get("truth")
    events: list[tuple] = []
    tj: list[int] = []
    truth_rows: list[list] = [[] for _ in per]
    lines: list[int] = []
    ok = True
    for k, s in enumerate(sig):
        if s[0] == "meas":
            obs0 = per[0][k][2]
            events.append(("meas", s[1], obs0.t, obs0.model, np.stack([items[k][2].z for items in per])))
        elif s[0] == "truth":
            tj.append(k)
            msg0 = per[0][k][1]
            lines.append(msg0.line)
            for i, items in enumerate(per):
                vals = items[k][1].values
                good = (names is not None and len(vals) == len(names)
                        and all(v.__class__ is float and v - v == 0.0 for v in vals))
                ok &= good
                truth_rows[i].append(vals if good else (np.nan,) * len(names or ()))
            events.append(("truth", len(tj) - 1))
        else:
            events.append(("reference", k))
    m = len(names or ())
    tv = np.array(truth_rows, float).reshape(len(per), len(tj), m) if names else np.zeros((len(per), len(tj), 0))
    tt = np.array([per[0][k][1].t for k in tj], float)
    return Lockstep(headers, events, tuple(names) if names else None, tt, tv,
                    np.array([e for e in range(len(events)) if events[e][0] == "truth"], np.int64), lines, ok and
                    bool(names), "text")


def _signature(item: tuple) -> tuple:
    if item[0] == "meas":
        obs = item[2]
        return ("meas", item[1], obs.t, getattr(obs.model, "bound", id(type(obs.model))), obs.z.shape)
    return (item[0], item[1].t)


# --------------------------------------------------------------------------- the fast path
class _CachedTrajectory:
    """A trajectory whose ``sample(t)`` is remembered by the times asked for (every seed's simulators ask
    for the same times); each caller gets its own copies of the arrays."""

    def __init__(self, traj: Any):
        self._traj = traj
        self._memo: dict[tuple, Any] = {}

    def sample(self, t: np.ndarray):
        t = np.asarray(t, float)
        key = (t.shape, t.tobytes())
        kin = self._memo.get(key)
        if kin is None:
            kin = self._memo[key] = self._traj.sample(t)
        return dataclasses.replace(kin, **{f.name: np.array(getattr(kin, f.name), copy=True)
                                           for f in dataclasses.fields(kin)})

    def __getattr__(self, name: str) -> Any:
        return getattr(self._traj, name)


@dataclass
class _Stream:
    name: str
    t: np.ndarray            # (K,) parsed times
    key: np.ndarray          # (K,) int microseconds: the text's sort key
    labels: dict[int, tuple]  # column -> labels (K,)
    numeric: list[int]       # numeric columns, in order
    V: np.ndarray            # (K, len(numeric)) rounded values
    width: int
    raw_t: np.ndarray
    raw_values: Any
    precision: int


def _stream(st: Any) -> _Stream:
    t_raw = np.asarray(st.t, float).reshape(-1)
    K = t_raw.size
    if st.table:
        arr = np.asarray(st.values, float)
        arr = arr if arr.ndim == 2 else arr.reshape(K, -1)
        width, labels, numeric, num = arr.shape[1], {}, list(range(arr.shape[1])), arr
    else:
        vals = st.values
        widths = set(map(len, vals))
        if len(widths) > 1:
            raise _Slow(f"{st.name}: messages of different lengths")
        width = widths.pop() if widths else 0
        labels, numeric, cols = {}, [], []
        for c, col in enumerate(zip(*vals)) if width else ():
            types = set(map(type, col))
            if types == {str}:
                labels[c] = col
            elif all(issubclass(tp, (int, float, np.integer, np.floating)) for tp in types):
                numeric.append(c)
                cols.append(np.array(col, float))
            else:
                raise _Slow(f"{st.name}: column {c} mixes labels and numbers")
        num = np.column_stack(cols) if cols else np.zeros((K, 0))
    if K and width == 0:
        raise _Slow(f"{st.name}: messages without values")
    V = round_text(num, st.precision)
    if not np.isfinite(V).all():
        raise _Slow(f"{st.name}: a non-finite value")
    key = np.rint(t_raw * 1e6).astype(np.int64)
    return _Stream(st.name, round_text(t_raw, 6), key, labels, numeric, V, width, t_raw, st.values, st.precision)


def _values(s: _Stream, k: int, row: np.ndarray) -> tuple:
    """The parsed values of message k given its numeric row."""
    out: list[Any] = [None] * s.width
    for c, lab in s.labels.items():
        out[c] = lab[k]
    for c, v in zip(s.numeric, row.tolist()):
        out[c] = v
    return tuple(out)


def from_simulation(system: Any, trials: Sequence[Any]) -> Lockstep:
    """The lockstep messages of the trials (one variant: the same scenario, different seeds), simulated
    without text where the text would give the same numbers (see the module docstring)."""
    from fusion.simulate.engine import render, simulate_parts
    from fusion.simulate.trajectory import TrajectoryError, build_trajectory

    from .trial import scenario_of

    sc = scenario_of(trials[0])
    try:
        traj: Any = _CachedTrajectory(build_trajectory(sc.trajectory, sc.dim, sc.duration))
    except TrajectoryError:
        traj = None                                  # simulate_parts raises the located error
    parts = [simulate_parts(sc, seed=tr.seed, trajectory=traj) for tr in trials]
    try:
        return _from_parts(system, parts)
    except _Slow:
        return from_texts(system, [render(p).splitlines() for p in parts])


def _header(lines: Sequence[str]):
    from fusion.logformat import Header, parse_comment

    h = Header()
    for line in lines:
        parse_comment("# " + line, h)
    return h


def _from_parts(system: Any, parts: list) -> Lockstep:
    from fusion.logformat import ParsedStream, format_line, iter_messages

    from .observe import observations

    headers = [_header(p.header) for p in parts]
    h0 = headers[0]
    if any(h.fields != h0.fields or h.repeating != h0.repeating for h in headers[1:]):
        raise NotLockstep("the seeds' recordings name different fields")
    per = [[_stream(st) for st in p.streams] for p in parts]
    s0 = per[0]
    for ss in per[1:]:
        if len(ss) != len(s0) or any(a.name != b.name or not np.array_equal(a.key, b.key) or
                                     not np.array_equal(a.t, b.t) or a.labels != b.labels or
                                     a.numeric != b.numeric for a, b in zip(ss, s0)):
            raise NotLockstep("the seeds' recordings differ in timing or content")
    # every distinct line shape (stream, labels) through the real parser: the same message?
    for s in s0:
        seen: set = set()
        lab_rows = list(zip(*s.labels.values())) if s.labels else [()] * s.t.size
        for k, lab in enumerate(lab_rows):
            if lab in seen:
                continue
            seen.add(lab)
            raw = s.raw_values[k].tolist() if isinstance(s.raw_values, np.ndarray) else s.raw_values[k]
            line = format_line(float(s.raw_t[k]), s.name, raw, precision=s.precision)
            got = list(iter_messages([line], ParsedStream(header=copy.deepcopy(h0))))
            want = _values(s, k, s.V[k])
            if (len(got) != 1 or not isinstance(got[0], Message) or got[0].t != s.t[k]
                    or got[0].sensor != s.name or got[0].values != want):
                raise _Slow(f"{s.name}: a line the parser reads otherwise")
    # merge in the text's order: (time in us, stream), stable
    key = np.concatenate([s.key for s in s0])
    order = np.concatenate([np.full(s.t.size, i) for i, s in enumerate(s0)])
    within = np.concatenate([np.arange(s.t.size) for s in s0])
    perm = np.lexsort((order, key))
    sid, kid = order[perm].tolist(), within[perm].tolist()
    nhead = len(parts[0].header)
    rank = np.empty(perm.size, np.int64)
    rank[perm] = np.arange(perm.size)
    offsets = np.cumsum([0] + [s.t.size for s in s0])
    N = len(parts)
    # observations per measurement stream
    obs: dict[int, tuple[list, list]] = {}
    for i, s in enumerate(s0):
        if s.name in ("truth", "reference"):
            continue
        sensor = system.sensors.get(s.name)
        if sensor is None:
            raise NotLockstep(f"a sensor not in the config ({s.name})")
        lines = rank[offsets[i]:offsets[i + 1]] + nhead + 1      # the text's line numbers
        obs[i] = observations(sensor, [ss[i] for ss in per], lines)
    truth_i = next((i for i, s in enumerate(s0) if s.name == "truth"), None)
    names = h0.fields.get("truth")
    events: list[tuple] = []
    tidx: list[int] = []
    tlines: list[int] = []
    for r, (i, k) in enumerate(zip(sid, kid)):
        if i == truth_i:
            tidx.append(len(events))
            tlines.append(r + nhead + 1)
            events.append(("truth", len(tidx) - 1))
        elif s0[i].name == "reference":
            events.append(("reference", r))
        else:
            models, zs = obs[i]
            if models[k] is not None:
                events.append(("meas", s0[i].name, float(s0[i].t[k]), models[k], zs[k]))
    if truth_i is None:
        tt, tv, ok = np.zeros(0), np.zeros((N, 0, 0)), False
    else:
        tt = s0[truth_i].t
        tv = np.stack([ss[truth_i].V for ss in per])
        ok = bool(names) and tv.shape[2] == len(names) and not s0[truth_i].labels
    return Lockstep(headers, events, tuple(names) if names else None, tt, tv, np.array(tidx, np.int64), tlines, ok)
