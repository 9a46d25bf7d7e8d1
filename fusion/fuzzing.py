"""Mutations of recorded log lines, for fuzzing ``fusion run``.

A mutation takes one real line of a recording (bytes, no newline) and returns what a noisy serial port,
a cut file or a hostile user could have left there instead: bit flips, truncation, duplicated, dropped
or swapped fields, extreme and non-finite numbers, unknown beacons, NUL bytes and invalid UTF-8.
Each mutation is a pure function of ``(line, op, i, j)`` with ``i``, ``j`` non-negative integers that pick
the byte, field or value, so a hypothesis strategy can draw (and shrink) them and a seeded script can
replay them. Used by tests/core/test_fuzz_recordings.py and experiments/fuzz_recordings.py.
"""
from __future__ import annotations

import json
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

#: Numbers that break naive code: overflow when squared or multiplied by a covariance, subnormals,
#: signed zero, a 400-digit integer, a cut fragment of a time stamp.
EXTREMES = (b"1e308", b"-1e308", b"1e300", b"1e200", b"1e20", b"-1e20", b"5e-324", b"-0", b"0", b"-1",
            b"1" + b"0" * 400, b"560000", b"1e-300", b"123456789012345678901234567890")
NONFINITE = (b"nan", b"inf", b"-inf", b"NaN", b"Infinity", b"1e999", b"-1e999")
JUNK = (b"\x00", b"\xff", b"\xc3", b"\xed\xa0\x80", b"\xfe\xff", b"\x00\x00\x00\x00", b"\x1b[2J", b"\r", b"\x80abc")
LABELS = (b"B9", b"B0", b"b1", b"B1 ", b"3", b"$GPGGA", b"", b"x" * 300)

#: The mutation operators; ``FIELD_OPS`` act on one field (index ``i`` modulo the field count).
OPS = ("bitflip", "truncate", "dup_field", "drop_field", "swap_fields", "extreme", "nonfinite", "label",
       "nul", "bad_utf8", "random_bytes", "repeat_line", "empty_field")
FIELD_OPS = frozenset({"dup_field", "drop_field", "swap_fields", "extreme", "nonfinite", "label", "empty_field"})


def mutate(line: bytes, op: str, i: int, j: int) -> bytes:
    """The line after mutation ``op``; ``i`` and ``j`` pick the position, field or replacement value."""
    fields = line.split(b",")
    k = i % len(fields)
    if op == "bitflip":
        if not line:
            return b"\x01"
        pos = i % len(line)
        return line[:pos] + bytes([line[pos] ^ (1 << (j % 8))]) + line[pos + 1:]
    if op == "truncate":
        return line[: i % max(len(line), 1)]
    if op == "dup_field":
        return b",".join(fields[:k + 1] + [fields[k]] + fields[k + 1:])
    if op == "drop_field":
        return b",".join(fields[:k] + fields[k + 1:])
    if op == "swap_fields":
        m = (k + 1 + j % max(len(fields) - 1, 1)) % len(fields)
        fields[k], fields[m] = fields[m], fields[k]
        return b",".join(fields)
    if op == "extreme":
        fields[k] = EXTREMES[j % len(EXTREMES)]
        return b",".join(fields)
    if op == "nonfinite":
        fields[k] = NONFINITE[j % len(NONFINITE)]
        return b",".join(fields)
    if op == "label":
        fields[k] = LABELS[j % len(LABELS)]
        return b",".join(fields)
    if op == "empty_field":
        fields[k] = b""
        return b",".join(fields)
    if op in ("nul", "bad_utf8"):
        junk = b"\x00" if op == "nul" else JUNK[1 + j % (len(JUNK) - 1)]
        pos = i % (len(line) + 1)
        return line[:pos] + junk + line[pos:]
    if op == "random_bytes":
        rng = random.Random(i * 1_000_003 + j)
        return bytes(rng.randrange(256) for _ in range(1 + j % 40)).replace(b"\n", b"\x00")
    if op == "repeat_line":
        return line + b"\n" + line
    raise ValueError(f"unknown mutation {op!r}; mutations are {OPS}")


def keep_time(original: bytes, mutated: bytes) -> bytes:
    """``mutated`` with the time stamp of ``original`` put back on each of its lines: a mutation of the
    values only (a stamp far ahead or overflowing is the run loop's time sanity, tested apart)."""
    t = original.split(b",", 1)[0]
    return b"\n".join(t + b"," + (line.split(b",", 1)[1] if b"," in line else line) for line in mutated.split(b"\n"))


#: Values a YAML field may be mutated to: non-finite, overflowing, wrong type, wrong shape, aliases,
#: tags PyYAML's safe loader refuses, deep nesting.
CONFIG_VALUES = (".nan", ".inf", "-.inf", "nan", "1e308", "1.0e+308", "-1", "0", "-0.0", "1.0e-320", "9" * 400,
                 "null", "~", "[]", "{}", "[1, 2, 3]", "[.nan, 1]", "[[1, 2], [3, 4]]", "[[1, 2], [3]]", "[[]]", "[[1]]", "'text'", "B9", "true",
                 "{type: nope}", "{type: ukf, alpha: 2}", "*undefined", "&a [*a]", "!!python/object/apply:os.getcwd []",
                 "[" * 200 + "]" * 200, "{a: 1, a: 2}", "1e999", "0x1F", "2001-01-01", "'1e6'", "[1e200, 1e200]",
                 "{p: 1.0e+200, v: 1}", "-1e308")
CONFIG_OPS = ("value", "delete_line", "duplicate_line", "truncate_line", "bitflip", "indent", "swap_lines")
#: Recording paths a config may hold that the system refuses or that never end when read (``{tmp}``: the
#: folder of :func:`hostile_files`, which makes the FIFO, the symlink loop and the file in place of a folder).
HOSTILE_PATHS = ("{tmp}/fifo", "{tmp}/loop", "{tmp}/file/x.log", "{tmp}", "{tmp}/empty.log", "{tmp}/binary.log",
                 "/proc/self/mem", "/dev/zero", "/dev/null", "/dev/tty", "/dev/urandom", "/", "/tmp/" + "a" * 5000,
                 "/tmp/" + "b" * 300 + "/x.log", "rec\\0.log", "")
#: Time offsets (s) put on one sensor, against the scheduler's max_latency (0.05-0.2 s in the configs fuzzed).
HOSTILE_OFFSETS = ("-0.5", "-1e9", "-0.0", "0.3", "-0.049", "1e10", "-1e10")
#: Mutations with a hostile value: ``recording`` (a path of HOSTILE_PATHS), ``time_offset`` (on the sensor
#: whose line is picked), ``numbers`` (thousands of plain numbers appended: a table given as a config).
HOSTILE_OPS = ("recording", "time_offset", "numbers")


def hostile_files(tmp: Path) -> Path:
    """Make in ``tmp`` the files HOSTILE_PATHS name: a FIFO without a writer, a symlink loop, a regular
    file where a folder is expected, an empty file and a binary one. Returns ``tmp``."""
    import os

    if not (tmp / "fifo").exists():
        os.mkfifo(tmp / "fifo")
        (tmp / "loop").symlink_to(tmp / "loop2")
        (tmp / "loop2").symlink_to(tmp / "loop")
        (tmp / "file").write_text("a file, not a folder\n")
        (tmp / "empty.log").write_bytes(b"")
        (tmp / "binary.log").write_bytes(bytes(range(256)) * 64)
    return tmp


def mutate_hostile(text: str, op: str, i: int, j: int, tmp: Path) -> str:
    """``text`` (a YAML config) after hostile mutation ``op`` (HOSTILE_OPS); ``i`` picks the line (a
    sensor for ``time_offset``), ``j`` the value; ``tmp`` holds :func:`hostile_files`."""
    lines = text.split("\n")
    if op == "recording":
        path = HOSTILE_PATHS[j % len(HOSTILE_PATHS)].replace("{tmp}", str(tmp))
        lines = [ln for ln in lines if not ln.startswith("recording:")]
        lines.insert(0, f'recording: "{path}"')
    elif op == "time_offset":
        sensors = [k for k, ln in enumerate(lines) if ln.startswith("  ") and not ln.startswith("   ")
                   and ln.rstrip().endswith(":") and "sensors:" in "\n".join(lines[:k])]
        if sensors:
            k = sensors[i % len(sensors)]
            lines.insert(k + 1, f"    time_offset: {HOSTILE_OFFSETS[j % len(HOSTILE_OFFSETS)]}")
    elif op == "numbers":
        lines.append("table:")
        lines.extend(f"  - {n}.5" for n in range(1000 + 30_000 * (j % 2)))
    else:
        raise ValueError(f"unknown hostile mutation {op!r}; mutations are {HOSTILE_OPS}")
    return "\n".join(lines)


def mutate_config(text: str, op: str, i: int, j: int) -> str:
    """``text`` (a YAML config) after mutation ``op`` of its line ``i`` (modulo the line count)."""
    lines = text.split("\n")
    k = i % len(lines)
    line = lines[k]
    if op == "value":
        head, sep, _ = line.partition(": ")
        if not sep:
            head, sep = (line.rstrip(":"), ": ") if line.rstrip().endswith(":") else (line, " ")
        lines[k] = head + sep + CONFIG_VALUES[j % len(CONFIG_VALUES)]
    elif op == "delete_line":
        del lines[k]
    elif op == "duplicate_line":
        lines.insert(k, line)
    elif op == "truncate_line":
        lines[k] = line[: j % (len(line) + 1)]
    elif op == "bitflip":
        if line:
            pos = j % len(line)
            lines[k] = line[:pos] + chr(ord(line[pos]) ^ (1 << (j % 7))) + line[pos + 1:]
    elif op == "indent":
        lines[k] = " " * (1 + j % 4) + line
    elif op == "swap_lines":
        m = (k + 1 + j % 5) % len(lines)
        lines[k], lines[m] = lines[m], lines[k]
    else:
        raise ValueError(f"unknown config mutation {op!r}; mutations are {CONFIG_OPS}")
    return "\n".join(lines)


def field_index(line: bytes, op: str, i: int) -> int | None:
    """Index of the field a field mutation acts on (0: the time stamp), None for other mutations."""
    return i % len(line.split(b",")) if op in FIELD_OPS else None


@dataclass
class Recording:
    """A recording as lines of bytes, with the indices of its message lines (not comments, not blank)."""

    lines: list[bytes]
    messages: list[int]

    @classmethod
    def read(cls, path: str | Path, until_s: float | None = None) -> "Recording":
        """Read a log; ``until_s`` keeps only the messages stamped before that time (a shorter replay)."""
        lines = []
        for raw in Path(path).read_bytes().splitlines():
            if until_s is not None and raw and not raw.startswith(b"#") and float(raw.split(b",", 1)[0]) >= until_s:
                continue
            lines.append(raw)
        return cls(lines, [n for n, raw in enumerate(lines) if raw.strip() and not raw.startswith(b"#")])

    def with_line(self, index: int, replacement: bytes) -> bytes:
        """The whole file with line ``index`` replaced."""
        out = list(self.lines)
        out[index] = replacement
        return b"\n".join(out) + b"\n"

    def sensor_of(self, index: int) -> str:
        return self.lines[index].split(b",")[1].decode()


def run_cli(config: str | Path, data: bytes, workdir: Path, name: str = "mutated") -> tuple[int, dict | None, str]:
    """``fusion run CONFIG --input <data> -q --summary-json`` in process: (exit code, summary or None, stderr)."""
    import contextlib
    import io

    from fusion.cli import main

    log, summary = workdir / f"{name}.log", workdir / f"{name}.json"
    log.write_bytes(data)
    summary.unlink(missing_ok=True)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(["run", str(config), "--input", str(log), "-q", "--no-progress", "--summary-json", str(summary)])
        except SystemExit as exc:  # argparse
            code = int(exc.code or 0)
    data_out = json.loads(summary.read_text()) if summary.exists() else None
    return code, data_out, err.getvalue()


def accounting_errors(base: dict, mutated: dict, mutated_sensor: str | None, op: str, blank: bool = False,
                      inputs: Sequence[str] = ()) -> list[str]:
    """What a one-line mutation took from lines it did not touch (empty when nothing): every configured
    sensor but the mutated line's receives exactly its lines of the unmutated run; the mutated sensor
    loses at most that one line (gains one for ``repeat_line``), and only by counting it malformed (under
    its own name or, when the mutation spoilt the name, under ``?``, another name or as an ignored sensor)
    unless the line became ``blank`` (a blank line is no message). The ``inputs`` sensors (role input: the
    IMU) other than the mutated one use every sample they used in the unmutated run."""
    problems = []
    for s in inputs:
        if s != mutated_sensor:
            got, want = mutated["sensors"].get(s, {}).get("used"), base["sensors"].get(s, {}).get("used")
            if got != want:
                problems.append(f"{s}: used {got} instead of {want}")

    def malformed(summary: dict, s: str) -> int:  # counted against s, '?' (no sensor) or an unknown sensor
        return (summary["sensors"].get(s, {}).get("malformed", 0) + summary["sensors"].get("?", {}).get("malformed", 0)
                + sum(summary.get("ignored_sensors", {}).values())
                + sum(v.get("malformed", 0) for k, v in summary["sensors"].items() if k not in base["sensors"]))

    for s, b in base["sensors"].items():
        if s == "?":
            continue
        m = mutated["sensors"].get(s, {})
        got, want = m.get("received", 0), b.get("received", 0)
        if s != mutated_sensor:
            if got != want:
                problems.append(f"{s}: received {got} instead of {want}")
        elif want - got not in ((-1, 0) if op == "repeat_line" else (0, 1)) or (
                want - got == 1 and not blank and malformed(mutated, s) <= malformed(base, s)):
            problems.append(f"{s}: received {got} (unmutated {want}), malformed {m.get('malformed')} "
                            f"(unmutated {b.get('malformed')})")
    return problems


def check_refusals(component, messages) -> int:
    """Feed ``messages`` to a decoder (``decode``), measurement model (``observe``), solver (``feed``, then
    ``flush``) or process model (``input_from``): each must be used or refused with MalformedMessage
    (RejectedMessage is one), never another exception, and
    what comes out must be usable: an Observation's ``z`` finite and of its model's ``dim``, its ``R``
    (if any) symmetric positive definite; a solver's or decoder's messages of finite numbers or labels.
    Returns how many were refused. The contract a plugin author can run on a component of their own."""
    import numpy as np

    from fusion.api import MalformedMessage, Message, Observation

    def usable(out) -> None:
        if isinstance(out, Observation):
            z = np.asarray(out.z, float)
            assert z.shape == (out.model.dim,) and np.all(np.isfinite(z)), f"unusable z {out.z!r}"
            if out.R is not None:
                R = np.asarray(out.R, float)
                assert R.shape == (z.size, z.size) and np.allclose(R, R.T), f"R {R!r} of z {z!r}"
                np.linalg.cholesky(R)   # LinAlgError: not positive definite
        elif isinstance(out, Message):
            assert all(isinstance(v, str) or np.isfinite(v) for v in out.values), f"non-finite {out!r}"
        elif isinstance(out, np.ndarray):   # a process model's input u
            assert out.shape == (component.input_dim,) and np.all(np.isfinite(out)), f"unusable input {out!r}"

    call = (getattr(component, "observe", None) or getattr(component, "decode", None)
            or getattr(component, "feed", None) or component.input_from)
    refused = 0
    for msg in messages:
        try:
            out = call(msg)
        except MalformedMessage:
            refused += 1
            continue
        for item in out if isinstance(out, list) else [out]:
            if item is not None:
                usable(item)
    for item in getattr(component, "flush", lambda: [])():
        usable(item)
    return refused
