"""The results file of a sweep: one row a trial, CSV (appended as trials finish, so an interrupted sweep
keeps what it did) or Parquet (pyarrow; rewritten whole at the end). ``read_rows`` gives the rows of an
existing file, for resuming and for the summary."""
from __future__ import annotations

import csv
import io
import math
import os
import stat
from pathlib import Path
from typing import Any, Iterable

from fusion.api import ConfigError

from .trial import HEALTH, METRICS, SMOOTHED, Trial

__all__ = ["check_output", "columns", "trial_fields", "read_rows", "CsvWriter", "write_parquet", "done_keys"]

TRIAL_COLUMNS = ("key", "config", "scenario", "seed", "filter")


def check_output(output: str, inputs: list[str]) -> None:
    """ConfigError unless ``output`` is a .csv or .parquet file in an existing directory and none of the
    ``inputs`` (the config, the scenario: never overwritten, also not through a link)."""
    out = Path(output)
    if out.suffix not in (".csv", ".parquet"):
        raise ConfigError(f"-o {output}: results file must end in .csv or .parquet")
    if out.exists() and out.is_dir():
        raise ConfigError(f"-o {output}: is a directory")
    _refuse_irregular(out, "-o ")
    if not out.parent.is_dir():
        raise ConfigError(f"-o {output}: no such directory {str(out.parent)!r}")
    for i in inputs:
        if out.exists() and Path(i).exists() and out.samefile(i):
            raise ConfigError(f"-o {output}: is the input {i} (it would be overwritten); use another file")


def _refuse_irregular(path: Path, option: str = "") -> None:
    """ConfigError when ``path`` exists (through a link) and is not a regular file: a device (/dev/zero
    would fill the memory when resumed from), a FIFO (reading it waits for a writer), a socket."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
        raise ConfigError(f"{option}{path}: not a regular file (a device, FIFO or socket); a results file is a "
                          ".csv or .parquet file the sweep appends to and resumes from: give a file name")


def columns(param_keys: Iterable[str], sensors: Iterable[str], smooth: bool) -> list[str]:
    """Column order: the trial, its params (``param.<key>``), status, metrics, NIS per sensor,
    smoothed metrics (with --smooth), the health rule's (``degraded``, ``health``), engine, error."""
    cols = list(TRIAL_COLUMNS) + [f"param.{k}" for k in param_keys] + ["smooth", "status"] + list(METRICS)
    cols += [f"nis_mean_{s}" for s in sensors]
    if smooth:
        cols += list(SMOOTHED)
    return cols + list(HEALTH) + ["engine", "error"]


def trial_fields(trial: Trial) -> dict[str, Any]:
    """The trial's own columns."""
    out: dict[str, Any] = {"key": trial.key(), "config": trial.config, "scenario": trial.scenario, "seed": trial.seed,
                           "filter": trial.filter or "", "smooth": trial.smooth}
    for k, v in trial.params:
        out[f"param.{k}"] = v
    return out


def _parse(v: str) -> Any:
    if v == "":
        return math.nan
    try:
        f = float(v)
    except ValueError:
        return {"True": True, "False": False}.get(v, v)
    return int(f) if f.is_integer() and "." not in v and "e" not in v.lower() and "nan" not in v.lower() else f


def read_rows(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a results file (CSV or Parquet); [] when it does not exist."""
    p = Path(path)
    if not p.exists():
        return []
    _refuse_irregular(p)
    if p.suffix == ".parquet":
        pq = _pyarrow()
        if p.stat().st_size == 0:
            return []
        try:
            return pq.read_table(p).to_pylist()
        except Exception as exc:  # pyarrow.ArrowInvalid and kin: not (all of) a Parquet file
            raise ConfigError(f"{p}: not a readable Parquet results file ({exc}); use another -o") from None
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            rd = csv.DictReader(fh)
            rows = []
            for r in rd:
                if None in r or any(v is None for v in r.values()):
                    continue   # a row cut short (an interrupted sweep) or overlong: its trial runs again
                rows.append({k: (_parse(v) if k not in ("key", "error", "config", "scenario", "filter")
                                 and not k.startswith("param.") else v) for k, v in r.items()})
            return rows
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ConfigError(f"{p}: not a readable CSV results file ({exc}); use another -o") from None


def done_keys(rows: list[dict[str, Any]]) -> set[str]:
    """Keys of the trials that finished (status ok): a resumed sweep skips them and retries failed ones."""
    return {r["key"] for r in rows if r.get("status") == "ok"}


def _pyarrow():
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise ConfigError("a .parquet results file needs pyarrow: pip install pyarrow (or write .csv)") from None
    return pq


class CsvWriter:
    """Appends rows to a CSV results file, flushed after each; writes the header to a new file and checks
    an existing file's header is the same columns (else ConfigError: another sweep's file)."""

    def __init__(self, path: str | Path, cols: list[str]):
        self.path = Path(path)
        self.cols = cols
        _refuse_irregular(self.path)
        existed = self.path.exists()
        exists = existed and self.path.stat().st_size > 0
        if exists and _cut_header(self.path, cols):
            # an interrupted first write: part of this sweep's header and no row, so nothing to keep
            self.path.write_text("", encoding="utf-8")
            exists = False
        if exists:
            with open(self.path, newline="", encoding="utf-8") as fh:
                head = next(csv.reader(fh), [])
            if head != cols:
                raise ConfigError(f"{self.path}: its columns are not this sweep's (another config, --param or "
                                  f"--smooth?); first difference: {_first_diff(head, cols)}; use another -o")
        try:
            self.fh = open(self.path, "a", newline="", encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"{self.path}: cannot write the results there ({exc.strerror})") from None
        self._created = not existed   # a failed write removes a file this sweep created
        self._good = self.fh.tell()   # size up to the last complete row: a failed write is cut back to it
        self.w = csv.DictWriter(self.fh, fieldnames=cols, extrasaction="ignore")
        if exists and not _ends_with_newline(self.path):
            self._guarded(lambda: self.fh.write("\n"))  # a row cut by an interrupted sweep: a line of its own
        if not exists:
            self._guarded(self.w.writeheader)

    def _guarded(self, write) -> None:
        """``write()`` then flush; on an OSError (disk full) the file is cut back to its last complete row
        (removed when this sweep created it and no row was written) and ConfigError names it (exit 2)."""
        try:
            write()
            self.fh.flush()
        except OSError as exc:
            self._undo()
            kept = "; the complete rows are kept, a rerun resumes from them" if self.path.exists() else ""
            raise ConfigError(f"{self.path}: cannot write the results there ({exc.strerror or exc}){kept}") from None
        self._good = self.fh.tell()

    def _undo(self) -> None:
        fh, self.fh = self.fh, None
        try:
            fh.close()
        except OSError:
            pass
        try:
            if self._created and self._good <= len(self._header()):
                os.unlink(self.path)
            else:
                os.truncate(self.path, self._good)
        except OSError:
            pass

    def _header(self) -> bytes:
        buf = io.StringIO()
        csv.DictWriter(buf, fieldnames=self.cols).writeheader()
        return buf.getvalue().encode("utf-8")

    def write(self, row: dict[str, Any]) -> None:
        if self.fh is None:
            raise ConfigError(f"{self.path}: the results file is closed (a write failed)")
        self._guarded(lambda: self.w.writerow({k: ("" if isinstance(v, float) and math.isnan(v) else v)
                                               for k, v in row.items()}))

    def close(self) -> None:
        if self.fh is not None:
            try:
                self.fh.close()
            except OSError:
                pass
            self.fh = None


def _cut_header(path: Path, cols: list[str]) -> bool:
    """Whether ``path`` holds only the beginning of the header this sweep writes (no newline yet)."""
    buf = io.StringIO()
    csv.writer(buf).writerow(cols)
    header = buf.getvalue()
    if path.stat().st_size >= len(header.encode("utf-8")):
        return False
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return False
    return header.startswith(text)


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as fh:
        fh.seek(-1, 2)
        return fh.read(1) == b"\n"


def _first_diff(a: list[str], b: list[str]) -> str:
    for x, y in zip(a, b):
        if x != y:
            return f"{x!r} in the file, {y!r} here"
    return f"{len(a)} columns in the file, {len(b)} here"


def write_parquet(path: str | Path, rows: list[dict[str, Any]], cols: list[str]) -> None:
    """All rows to a Parquet file (atomically: a temporary file renamed)."""
    pq = _pyarrow()
    import pyarrow as pa
    table = pa.Table.from_pylist([{c: r.get(c) for c in cols} for r in rows])
    tmp = Path(str(path) + ".tmp")
    try:
        pq.write_table(table, tmp)
        if os.path.exists(path):   # the rewritten results keep the file's permission bits
            os.chmod(tmp, stat.S_IMODE(os.stat(path).st_mode))
        os.replace(tmp, path)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write the results there ({exc.strerror or exc})") from None
    finally:
        if tmp.exists():   # a failed write (disk full) leaves no temporary file beside the results
            try:
                tmp.unlink()
            except OSError:
                pass
