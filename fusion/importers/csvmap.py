"""Importer ``csv``: a CSV dataset through a mapping file (YAML), docs/import.md "CSV datasets".

The mapping says which column is time (seconds, ms, us, ns or an ISO 8601 date-time), which columns make
which sensor's fields, or which columns hold the ranges to which beacon (``pairs``: one multi-pair range line
a row), the unit scale and offset of each field (``value * scale + offset``), a time offset per sensor
(added to its times: a known latency or the clock offset between two recorders), and which columns are the
ground truth (written as ``truth`` lines, never fused). A sensor (or the truth) may come from another file
with its own time column (``file:``, relative to the input file's folder).

Only the columns the mapping names are parsed, and only in rows in ``--start``..``--end``; the time column is
read to the end of the file (a row inside the span may follow a later one). ``time.zero: first`` is the
earliest time in the column; rows out of time order are said in a note and sorted.
"""
from __future__ import annotations

import csv
import datetime as dt
from array import array
import math
import re
from pathlib import Path
from typing import Any, Iterator, Literal

import numpy as np
from pydantic import Field, ValidationError, field_validator, model_validator

from fusion.api import ConfigError, ImportedLog, Importer, ImportRequest, InputError, Params, Stream
from fusion.importers.field_order import reading_order
from fusion.logformat import _LABEL, _SENSOR

_UNIT = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
CSV_FMT = ".12g"   # values read from text: 12 significant digits keep what a dataset prints


class TimeSpec(Params):
    """The time column: ``unit`` ``s``/``ms``/``us``/``ns`` (numbers) or ``iso`` (ISO 8601 date-time text, a
    naive one taken as UTC, or any text ``format`` of datetime.strptime). ``zero``: ``first`` (t = 0 at the
    earliest time of the first file read, the input file when it maps a sensor; not the first row's time
    when the rows are out of order), ``none`` (times as they are, in s), or a date-time / number of s to subtract."""

    column: str | int
    unit: Literal["s", "ms", "us", "ns", "iso"] = "s"
    format: str | None = None
    zero: str | float = "first"

    @field_validator("zero", mode="before")
    @classmethod
    def _date_time_zero(cls, v):
        # YAML reads an unquoted 2026-03-29T00:59:30Z as a date-time (a date alone as a date): as ISO text
        if isinstance(v, dt.datetime):
            return v.isoformat()
        if isinstance(v, dt.date):
            return dt.datetime(v.year, v.month, v.day).isoformat()
        return v


class CsvOptions(Params):
    """How the file is read: ``delimiter`` (``,`` ``;`` tab, ``whitespace``; default: detected), whether the
    first row names the columns (``header``), comment lines, rows to skip before the header, and the cell
    texts that mean "no value" (that row then has no sample of that sensor, or no pair of that beacon)."""

    delimiter: str | None = None
    header: bool = True
    comment: str | None = "#"
    skip_rows: int = Field(0, ge=0)
    missing: list[str] = ["", "nan", "NaN", "NAN", "NA", "null", "None"]


class SensorMap(Params):
    """One sensor (or the truth): ``fields`` (field name -> column) or ``pairs`` (beacon name -> range column);
    ``scale``/``offset`` (one number, or per field / beacon); ``time_offset`` s added to its times; ``valid``
    [lo, hi] (outside: no value); ``units`` written to the header; ``file``/``time``/``csv`` when it comes from
    another file."""

    fields: dict[str, str | int] | None = None
    pairs: dict[str, str | int] | None = None
    scale: float | dict[str, float] = 1.0
    offset: float | dict[str, float] = 0.0
    time_offset: float = 0.0
    valid: tuple[float, float] | None = Field(None, description="[lo, hi]: a value outside, after scale and "
                                              "offset, counts as no value (a logger's 0 or 65535 for 'no range')")
    units: str | None = None
    file: str | None = None
    time: TimeSpec | None = None
    csv: CsvOptions | None = None

    @model_validator(mode="after")
    def _one_layout(self):
        if (self.fields is None) == (self.pairs is None):
            raise ValueError("give exactly one of 'fields' (field -> column) or 'pairs' (beacon -> column)")
        keys = list(self.fields or self.pairs or {})
        if not keys:
            raise ValueError("names no columns")
        pat = _NAME if self.fields is not None else _LABEL
        bad = [k for k in keys if not pat.match(str(k))]
        if bad:
            raise ValueError(f"names {bad} are not valid field/beacon names (a letter first, then letters, digits, _)")
        for what in ("scale", "offset"):
            v = getattr(self, what)
            if isinstance(v, dict):
                unknown = sorted(set(v) - set(keys))
                if unknown:
                    raise ValueError(f"{what} names {unknown}, which are not among {keys}")
                vals = list(v.values())
            else:
                vals = [v]
            if not all(math.isfinite(x) for x in vals):
                raise ValueError(f"{what} must be finite")
        return self


class Mapping(Params):
    """A mapping file: the default ``time`` column and ``csv`` options, the ``sensors``, the ``truth``, and
    header metadata: ``beacons`` (name -> position, m) and free ``meta`` (key -> text)."""

    time: TimeSpec | None = None
    csv: CsvOptions = CsvOptions()
    sensors: dict[str, SensorMap] = {}
    truth: SensorMap | None = None
    beacons: dict[str, list[float]] = {}
    meta: dict[str, str] = {}

    @field_validator("sensors")
    @classmethod
    def _names(cls, v):
        for name in v:
            if not _SENSOR.match(name) or name in ("truth", "reference"):
                raise ValueError(f"{name!r} is not a usable sensor name (letters, digits, _ . -; not truth/reference)")
        return v

    @model_validator(mode="after")
    def _times(self):
        for name, s in [*self.sensors.items(), ("truth", self.truth)]:
            if s is not None and s.time is None and self.time is None:
                raise ValueError(f"{name}: no time column: give 'time:' at the top or in the sensor")
        if self.truth is not None and self.truth.pairs is not None:
            raise ValueError("truth takes 'fields' (state element names such as px py pz qw ...), not 'pairs'")
        return self


def load_mapping(path: str) -> Mapping:
    from fusion.yamlsource import load_yaml, pydantic_errors

    doc = load_yaml(path)
    try:
        return Mapping.model_validate(doc.data)
    except ValidationError as exc:
        raise pydantic_errors(doc, exc) from None


class CsvImporter(Importer):
    """CSV datasets through a mapping file (--map MAP.yaml).

    Time column (s/ms/us/ns or ISO date-time),
    columns -> sensor fields or beacon/range pairs, unit scales and offsets, per-sensor time offsets, ground
    truth -> ``truth`` lines, several files (``file:``). See docs/import.md."""

    name = "csv"
    suffixes = (".csv", ".tsv", ".txt")
    sensors = ()   # whatever the mapping names

    def read(self, path: str, request: ImportRequest) -> ImportedLog:
        if not request.mapping:
            raise ConfigError(f"{path}: a CSV needs a mapping file: --map MAP.yaml (docs/import.md)")
        mapping = load_mapping(request.mapping)
        wanted = {n: s for n, s in mapping.sensors.items() if request.wants(n)}
        if mapping.truth is not None and request.wants("truth"):
            wanted["truth"] = mapping.truth
        if request.sensors is not None:
            unknown = sorted(request.sensors - set(wanted))
            if unknown:
                raise ConfigError(f"--sensors: {', '.join(unknown)} not in {request.mapping} "
                                  f"(it maps: {', '.join([*mapping.sensors, *(['truth'] if mapping.truth else [])])})")
        if not wanted:
            raise ConfigError(f"{request.mapping}: maps no sensors (give 'sensors:' or 'truth:')")
        base = Path(path).parent
        files: dict[Path, list[str]] = {Path(path): []}
        for name, s in wanted.items():
            files.setdefault(base / s.file if s.file else Path(path), []).append(name)
        log = ImportedLog()
        log.meta["source"] = f"{Path(path).name} (CSV, mapping {Path(request.mapping).name})"
        for k, v in mapping.meta.items():
            log.meta[k] = v
        for b, pos in mapping.beacons.items():
            log.meta[f"beacon {b}"] = " ".join(f"{x:g}" for x in pos)
        zero = None
        collected: dict[str, tuple[list[float], list[Any]]] = {}
        for fpath, names in files.items():
            if not names:
                continue
            if fpath != Path(path):
                log.inputs.append(str(fpath))
            tspec = wanted[names[0]].time or mapping.time
            specs = {n: wanted[n] for n in names}
            for n, s in specs.items():
                if (s.time or mapping.time) != tspec:
                    raise ConfigError(f"{request.mapping}: sensors {names} read {fpath.name} with different time "
                                      "columns; give each file one time spec")
            opts = specs[names[0]].csv or mapping.csv
            own = wanted[names[0]].time is not None   # a file with its own time spec has its own clock and zero
            z = _read_file(fpath, tspec, opts, specs, request, None if own else zero, collected,  # type: ignore[arg-type]
                           log.notes)
            if z is not None and z != 0.0:
                key = "time_zero" if not own else f"time_zero {fpath.name}"
                log.meta[key] = (dt.datetime.fromtimestamp(z, dt.timezone.utc).isoformat() if tspec.unit == "iso"
                                 else f"{z:.9g} s")
            if not own:
                zero = z
        for name, s in wanted.items():
            t, rows = collected.get(name, ([], []))
            order = np.argsort(np.asarray(t, float), kind="stable")
            tt = np.asarray(t, float)[order]
            meta = {"units": s.units} if s.units else {}
            if s.time_offset:
                meta["time_offset_s"] = f"{s.time_offset:g} (added to the dataset's times)"
            if s.pairs is not None:
                log.streams.append(Stream(name, ("beacon", "range"), tt, rows=[rows[i] for i in order], meta=meta,
                                          repeat=True))
            else:
                m = len(s.fields or {})
                vals = np.frombuffer(rows, float).reshape(len(tt), m)[order] if len(tt) else np.zeros((0, m))
                names = tuple(s.fields or {})
                fixed = reading_order(names) if name not in ("truth", "reference") else None
                if fixed is not None:   # fusion run reads values by position: written in the order it reads
                    vals = vals[:, [names.index(f) for f in fixed]]
                    log.notes.append(f"{name}: the mapping lists {' '.join(names)}; written as {' '.join(fixed)}, "
                                     "the order the components read them")
                    names = fixed
                log.streams.append(Stream(name, names, tt, vals, (CSV_FMT,) * vals.shape[1], meta))
        return log


def _abs_time(text: str, spec: TimeSpec) -> float:
    """Seconds (POSIX seconds for date-times) of a time cell; ValueError when it is not one."""
    if spec.unit != "iso":
        v = float(text) * _UNIT[spec.unit]
        if not math.isfinite(v):
            raise ValueError("not finite")
        return v
    if spec.format:
        d = dt.datetime.strptime(text.strip(), spec.format)
    else:
        d = dt.datetime.fromisoformat(text.strip())
    if d.tzinfo is None:
        d = d.replace(tzinfo=dt.timezone.utc)
    return d.timestamp()


def _zero_of(spec: TimeSpec, first: float | None) -> float:
    z = spec.zero
    if isinstance(z, (int, float)):
        return float(z)
    if z == "first":
        return first if first is not None else 0.0
    if z == "none":
        return 0.0
    try:
        return float(z)                     # s
    except ValueError:
        pass
    # a date-time: POSIX seconds, whatever the column's unit (a numeric column is then POSIX time in its unit);
    # read as the column's own date-times are (its format first, if any), else as ISO 8601
    iso = spec.model_copy(update={"unit": "iso", "format": None})
    for s in ((spec,) if spec.unit == "iso" and spec.format else ()) + (iso,):
        try:
            return _abs_time(z, s)
        except ValueError:
            continue
    raise ConfigError(f"time.zero: {z!r} is neither 'first', 'none', a number (s) nor an ISO 8601 date-time")


def _rows(path: Path, opts: CsvOptions) -> Iterator[tuple[int, list[str]]]:
    """(line number, cells) of the data rows, after the skipped rows; the header row comes first."""
    try:
        fh = open(path, encoding="utf-8-sig", newline="")
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    with fh:
        try:
            head = fh.read(8192)
        except UnicodeDecodeError as exc:
            raise InputError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
        if "\x00" in head:
            raise InputError(f"{path}: binary data, not a CSV text file")
        fh.seek(0)
        delim = opts.delimiter
        if delim is None:
            sample = "\n".join(line for line in head.splitlines()[opts.skip_rows:]
                               if not (opts.comment and line.startswith(opts.comment)))
            try:
                delim = csv.Sniffer().sniff(sample, delimiters=",;\t|").delimiter
            except csv.Error:
                # the sniffer wants every sampled row alike (one ragged row of a short file defeats it): the
                # delimiter the first row (the header) is split by most, else whitespace
                first = sample.split("\n", 1)[0]
                counts = {d: first.count(d) for d in ",;\t|"}
                best = max(counts, key=counts.get)
                delim = best if counts[best] else "whitespace"
        pos = [0]

        def lines():
            for n, line in enumerate(fh, 1):
                pos[0] = n
                if n <= opts.skip_rows:
                    continue
                s = line.strip()
                if not s or (opts.comment and s.startswith(opts.comment)):
                    continue
                yield line

        try:
            if delim == "whitespace":
                for line in lines():
                    yield pos[0], line.split()
            else:
                for cells in csv.reader(lines(), delimiter="\t" if delim in ("tab", "\\t") else delim):
                    if cells:
                        yield pos[0], cells
        except UnicodeDecodeError as exc:
            raise InputError(f"{path}:{pos[0] + 1}: not UTF-8 text ({exc.reason})") from None
        except csv.Error as exc:
            raise InputError(f"{path}:{pos[0]}: {exc}") from None


def _index(col: str | int, names: list[str] | None, path: Path, where: str) -> int:
    if isinstance(col, int):
        if names is not None and col >= len(names):
            raise ConfigError(f"{where}: column {col} is past the last column of {path.name} ({len(names)} columns)")
        return col
    if names is None:
        raise ConfigError(f"{where}: column {col!r} by name, but the mapping says the file has no header row "
                          "(csv.header: false): use 0-based column numbers")
    if names.count(col) > 1:
        dups = [i for i, n in enumerate(names) if n == col]
        raise ConfigError(f"{where}: column {col!r} is in the header of {path.name} {len(dups)} times (columns "
                          f"{', '.join(map(str, dups))}): give the 0-based column number instead")
    try:
        return names.index(col)
    except ValueError:
        stripped = [n.strip() for n in names]
        if col.strip() in stripped:
            return stripped.index(col.strip())
        shown = ", ".join(repr(n if len(n) <= 40 else n[:37] + "...") for n in names[:20]) + (f", ... ({len(names)} in all)" if len(names) > 20 else "")
        raise ConfigError(f"{where}: no column {col!r} in {path.name} (columns: {shown})") from None


def _show_time(ta: float, spec: TimeSpec) -> str:
    """A time cell's value as the user reads it: the date-time (ISO) or seconds."""
    if spec.unit == "iso":
        return dt.datetime.fromtimestamp(ta, dt.timezone.utc).isoformat(timespec="milliseconds")
    return f"{ta / _UNIT[spec.unit]:.9g} {spec.unit}"


def _read_file(path: Path, tspec: TimeSpec, opts: CsvOptions, specs: dict[str, SensorMap], request: ImportRequest,
               zero: float | None, out: dict[str, tuple[list[float], list[Any]]], notes: list[str]) -> float | None:
    """Read the mapped columns of ``path`` into ``out``; the zero (s) it used. ``zero: first`` is the earliest
    time in the column, not the first row's: when a row earlier than the first one turns up, the times read
    are shifted to that zero, or with --start/--end the file is read again (rows out of time order are said
    in a note, and sorted by the caller)."""
    zero_here = zero is None and tspec.zero == "first"
    z, earliest, disorder, incomplete = _read_pass(path, tspec, opts, specs, request, zero, out)
    if disorder is not None:
        lineno, ta, before = disorder
        notes.append(f"{path.name}: rows not in time order (line {lineno}: {_show_time(ta, tspec)} after "
                     f"{_show_time(before, tspec)}); the rows are sorted by time"
                     + (f", and t = 0 is the earliest time, {_show_time(earliest, tspec)}" if zero_here
                        and z is not None and earliest < z else ""))
    if zero_here and z is not None and earliest < z:
        if (request.start is None and request.end is None) or not path.is_file():
            for sname in specs:   # no span to redo (or a stream that cannot be read twice): shift the times
                ts = out[sname][0]
                if len(ts):
                    np.frombuffer(ts, float)[:] += z - earliest
            if request.start is not None or request.end is not None:
                notes.append(f"{path.name}: --start/--end were applied with t = 0 at the first row (the input "
                             "cannot be read twice)")
        else:   # the span is on the new time axis: read again
            for sname in specs:
                out.pop(sname, None)
            z, _, _, incomplete = _read_pass(path, tspec, opts, specs, request, earliest, out)
        z = earliest
    for sname, n in incomplete.items():
        notes.append(f"{sname}: {n} row(s) of {path.name} with some but not all of its columns dropped")
    return z


def _read_pass(path: Path, tspec: TimeSpec, opts: CsvOptions, specs: dict[str, SensorMap], request: ImportRequest,
               zero: float | None, out: dict[str, tuple[list[float], list[Any]]]):
    """One pass over the file: (zero, the earliest absolute time, (line, time, the later time before it) of
    the first row out of order or None, rows with only some columns per sensor). Every row is read to the
    end of the file (a row inside the span may come after a later one: the time column is never assumed to
    go only forward), but a cell is converted only in rows inside the span."""
    rows = _rows(path, opts)
    names: list[str] | None = None
    if opts.header:
        first = next(rows, None)
        if first is None:
            raise InputError(f"{path}: no header row (the file is empty)")
        names = first[1]
    mp = Path(request.mapping).name if request.mapping else "mapping"
    ti = _index(tspec.column, names, path, f"{mp}: time.column")
    plan = []
    for sname, s in specs.items():
        cols = s.fields if s.fields is not None else s.pairs
        idx = [_index(c, names, path, f"{mp}: {sname}.{k}") for k, c in cols.items()]  # type: ignore[union-attr]
        keys = list(cols)  # type: ignore[arg-type]
        scale = [s.scale.get(k, 1.0) if isinstance(s.scale, dict) else s.scale for k in keys]
        offset = [s.offset.get(k, 0.0) if isinstance(s.offset, dict) else s.offset for k in keys]
        store = (array("d"), array("d") if s.fields is not None else [])   # flat float64: ~8 B a value
        plan.append((sname, s, keys, idx, scale, offset, out.setdefault(sname, store)))
    missing = set(opts.missing)
    ta_prev, earliest = -math.inf, math.inf
    disorder = None
    incomplete: dict[str, int] = {}
    for lineno, cells in rows:
        where = f"{path}:{lineno}"
        try:
            ta = _abs_time(cells[ti], tspec)
        except IndexError:
            raise InputError(f"{where}: {len(cells)} columns, no time column {tspec.column!r}") from None
        except (ValueError, OverflowError):
            raise InputError(f"{where}: time {cells[ti]!r} is not a time in {tspec.unit}"
                             + (f" (format {tspec.format!r})" if tspec.format else "")) from None
        if zero is None:
            zero = _zero_of(tspec, ta)
        t = ta - zero
        if ta < ta_prev and disorder is None:
            disorder = (lineno, ta, ta_prev)
        ta_prev = max(ta_prev, ta)
        earliest = min(earliest, ta)
        for sname, s, keys, idx, scale, offset, (ts, vals) in plan:
            lo, hi = s.valid if s.valid is not None else (-math.inf, math.inf)
            ts_s = t + s.time_offset
            if (request.start is not None and ts_s < request.start) or (request.end is not None and ts_s > request.end):
                continue
            got: list[Any] = []
            for k, i, a, b in zip(keys, idx, scale, offset):
                text = cells[i].strip() if i < len(cells) else ""
                if text in missing:
                    got.append(None)
                    continue
                try:
                    v = float(text)
                except ValueError:
                    raise InputError(f"{where}: {sname}.{k}: {text!r} is not a number (column "
                                     f"{names[i] if names and i < len(names) else i})") from None
                if not math.isfinite(v):
                    got.append(None)
                    continue
                v = v * a + b
                got.append(v if lo <= v <= hi else None)
            if s.pairs is not None:
                row = tuple(x for k, v in zip(keys, got) if v is not None for x in (k, v))
                if row:
                    ts.append(ts_s)
                    vals.append(row)
            elif all(v is not None for v in got):
                ts.append(ts_s)
                vals.extend(got)
            elif any(v is not None for v in got):
                incomplete[sname] = incomplete.get(sname, 0) + 1
    return zero, earliest, disorder, incomplete
