"""The one run loop (fusion.pipeline): reusable systems, streaming truth equal to the whole-recording
reference, bounded memory, hooks, Ctrl-C."""
from __future__ import annotations

import json
import os
import re
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from fusion.errors import InputError

from fusion import hookimpl, pipeline
from fusion.api import Message, Source
from fusion.cli import main
from fusion.config import load_system, wire, SystemSpec
from fusion.metrics import ErrorTracker, Truth
from fusion.registry import make_plugin_manager
from fusion.sinks.plot_recorder import ExtremeDecimator
from fusion.sources.recording import open_lines
from fusion.truth_stream import TruthWindow

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "configs" / "example_2d.yaml"
ABPS = ROOT / "configs" / "abps_ins.yaml"
TIMINGS = {"wall_s", "us_per_predict", "us_per_update"}


def _same(a: dict, b: dict) -> None:
    assert {k: v for k, v in a.items() if k not in TIMINGS} == {k: v for k, v in b.items() if k not in TIMINGS}


@pytest.mark.parametrize("config", [EXAMPLE, ABPS], ids=["example_2d", "abps_ins"])
def test_a_system_runs_twice_with_identical_results_and_is_not_modified(config):
    system = load_system(config)
    first = pipeline.run(system, system.recording)
    second = pipeline.run(system, system.recording)
    _same(first.summary, second.summary)
    np.testing.assert_array_equal(first.last.belief.x, second.last.belief.x)
    assert first.summary["sensors"] == second.summary["sensors"]
    assert all(v == 0 for s in system.sensors.values() for v in s.counters.values())
    assert not getattr(system.filter, "counters", {})


def _reference_errors(system, path):
    """The pre-streaming computation: every estimate kept, the whole truth, then one ErrorTracker."""
    kept = pipeline.Collect()
    nis = []

    class Nis:
        def on_estimate(self, est):
            if est.update is not None:
                nis.append((est.sensor, est.t, est.update.nis, est.update.innovation.size, est.update.accepted))

        def close(self):
            pass

    result = pipeline.run(system, path, [kept, Nis()])
    truth = Truth.from_recording(path)
    ev = system.spec.evaluation
    tr = ErrorTracker(system.layout, truth, settle_s=ev.settle_s, position=ev.position)
    for est in kept.estimates:
        tr.add(est)
    for sensor, t, v, dim, accepted in nis:
        tr.add_nis(sensor, v, dim, t=t, accepted=accepted)
    return result.summary, tr.summary()


@pytest.mark.parametrize("config", [EXAMPLE, ABPS], ids=["example_2d", "abps_ins"])
def test_streamed_errors_equal_the_whole_truth_reference(config):
    system = load_system(config)
    summary, ref = _reference_errors(system, system.recording)
    errors = dict(summary["errors"])
    errors.pop("position_elements", None)
    assert errors == ref["errors"]
    assert summary["consistency"] == ref["consistency"]


def _truth_stream(n, rng, period=0.01, gap=None):
    t = np.cumsum(np.full(n, period) + rng.uniform(-1e-4, 1e-4, n))
    if gap is not None:
        t[gap:] += 0.2
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q = np.cumsum(q * 0.05, axis=0) + [1, 0, 0, 0]
    ang = np.cumsum(rng.normal(0, 0.8, n))  # wraps often
    vals = np.column_stack([rng.normal(size=(n, 2)).cumsum(0), q, (ang + np.pi) % (2 * np.pi) - np.pi])
    names = ("px", "py", "qw", "qx", "qy", "qz", "psi")
    return t, vals, names


def test_truth_window_interpolates_as_the_whole_truth_does():
    rng = np.random.default_rng(4)
    t, vals, names = _truth_stream(3000, rng, gap=1500)
    whole = Truth(t, vals, names).with_angles(["psi"])
    win = TruthWindow(names, max_samples=100_000).with_angles(["psi"])
    for ti, v in zip(t, vals):
        win.add(Message(float(ti), "truth", tuple(v.tolist())))
    win.period = whole.period
    queries = np.concatenate([rng.uniform(t[0] - 0.02, t[-1] + 0.02, 2000), t[:50], [t[1499] + 0.1]])
    for q in queries:
        a, b = whole.row(float(q)), win.row(float(q))
        assert (a is None) == (b is None), q
        if a is not None:
            np.testing.assert_allclose(b, a, rtol=0, atol=1e-12)


def test_truth_window_stays_bounded_and_skips_bad_rows():
    win = TruthWindow(("px", "py"), max_samples=500)
    for k in range(10_000):
        win.add(Message(k * 0.01, "truth", (float(k), 0.0)))
        win.forget_before(k * 0.01 - 1.0)
    assert len(win) <= 500 and win.received == 10_000
    assert not win.add(Message(101.0, "truth", (1.0,))) and not win.add(Message(101.0, "truth", ("x", 2.0)))
    assert win.skipped == 2
    assert win.row(99.985)[0] == pytest.approx(9998.5) and win.row(99.995)[0] == 9999.0  # held half a period


def _long_stream(n_messages: int):
    """A 2-D walk with ranges to four beacons and truth at every range: lines made on the fly."""
    rng = np.random.default_rng(1)
    beacons = {"B1": (0, 0), "B2": (20, 0), "B3": (20, 20), "B4": (0, 20)}
    yield "# fields truth px py vx vy\n"
    p, v = np.array([5.0, 5.0]), np.array([0.5, 0.2])
    for k in range(n_messages):
        t = 0.025 * k
        v = np.clip(v + rng.normal(0, 0.02, 2), -1, 1)
        p = np.clip(p + 0.025 * v, 1, 19)
        name = "B%d" % (k % 4 + 1)
        r = math.dist(p, beacons[name]) + float(rng.normal(0, 0.1))
        px, py, vx, vy = (float(a) for a in (*p, *v))
        yield f"{t!r},truth,{px!r},{py!r},{vx!r},{vy!r}\n"
        yield f"{t!r},uwb,{name},{r!r}\n"


def _peak_kib(n_messages: int) -> tuple[float, dict]:
    system = load_system(EXAMPLE, filter_override="ekf")
    tracemalloc.start()
    try:
        result = pipeline.run(system, _long_stream(n_messages))
        peak = tracemalloc.get_traced_memory()[1] / 1024.0
    finally:
        tracemalloc.stop()
    return peak, result.summary


def test_memory_does_not_grow_with_the_length_of_a_run():
    short, s1 = _peak_kib(4_000)
    long, s2 = _peak_kib(16_000)
    assert s2["errors"]["samples"] > 3.5 * s1["errors"]["samples"]  # four times the estimates compared
    assert long < short + 256.0, (short, long)                      # but no more memory (KiB)


class Watcher:
    """A plugin that watches runs through the observation hooks."""

    def __init__(self):
        self.estimates, self.events, self.ends = 0, {}, []

    @hookimpl
    def fusion_on_estimate(self, estimate, system):
        assert system.layout.n == estimate.belief.x.size
        self.estimates += 1

    @hookimpl
    def fusion_on_event(self, event):
        self.events[event.kind] = self.events.get(event.kind, 0) + 1

    @hookimpl
    def fusion_on_run_end(self, summary):
        self.ends.append(summary)


def test_observation_hooks_see_every_estimate_event_and_the_end(tmp_path):
    watcher = Watcher()
    _, registry = make_plugin_manager(extra_plugins=[watcher])
    log = tmp_path / "bad.log"
    lines = (ROOT / "recordings" / "example_2d.log").read_text().splitlines()
    lines.insert(40, "0.49,uwb,B1,notanumber")   # stamped in its place (1.5 s: a wild stamp, dropped for its time)
    lines.insert(41, "0.49,mystery,1.0")
    log.write_text("\n".join(lines) + "\n")
    system = load_system(EXAMPLE, registry=registry)
    kept = pipeline.Collect()
    result = pipeline.run(system, log, [kept])
    assert watcher.estimates == len(kept.estimates) > 2000
    assert watcher.events == result.summary["events"] and watcher.events["malformed"] == 1
    assert watcher.ends == [result.summary]


def test_a_failing_hook_is_named_and_dropped_and_the_run_goes_on(capsys):
    """A hook that raises does not end the run as an internal error (the summary never written, a cut
    output renamed as if complete): the failing implementation is named (the plugin, where), not called
    again, and the run, the other implementations and the summary go on complete."""
    class Broken:
        calls = 0

        @hookimpl
        def fusion_on_estimate(self):
            Broken.calls += 1
            raise ValueError("boom")

    watcher = Watcher()
    _, registry = make_plugin_manager(extra_plugins=[Broken(), watcher])
    system = load_system(EXAMPLE, registry=registry)
    kept = pipeline.Collect()
    result = pipeline.run(system, system.recording, [kept])
    plain = pipeline.run(load_system(EXAMPLE), load_system(EXAMPLE).recording)
    assert Broken.calls == 1 and watcher.estimates == len(kept.estimates) == plain.stats.estimates > 2000
    assert len(result.plugin_errors) == 1
    assert re.fullmatch(r"plugin .*Broken: its fusion_on_estimate hook raised ValueError: boom at t = \d+\.\d{3} s; "
                        r"it was not called again", result.plugin_errors[0]), result.plugin_errors
    assert result.summary["plugin_errors"] == list(result.plugin_errors)
    assert result.summary["errors"] == plain.summary["errors"] and watcher.ends      # complete, run_end called
    assert "plugin_errors" not in plain.summary


def test_a_run_end_hook_gets_a_copy_of_the_summary():
    """A fusion_on_run_end hook that edits the dict it is given (pops 'errors', sets used = -1) does not
    rewrite the table printed and the --summary-json written after it."""
    class Editing:
        @hookimpl
        def fusion_on_run_end(self, summary):
            summary.pop("errors")
            next(iter(summary["sensors"].values()))["used"] = -1
            summary["health"]["final_estimate_finite"] = False

    _, registry = make_plugin_manager(extra_plugins=[Editing()])
    system = load_system(EXAMPLE, registry=registry)
    result = pipeline.run(system, system.recording)
    assert "errors" in result.summary and all(s["used"] >= 0 for s in result.summary["sensors"].values())
    assert result.summary["health"]["final_estimate_finite"] is True and not result.plugin_errors


def test_a_failing_plugin_sink_is_dropped_its_file_discarded_and_the_run_goes_on(tmp_path):
    """A plugin's sink whose on_event (or on_estimate, or close) raises does not end the run, nor is its cut
    file renamed over the target (or its .tmp left behind): it is named, gets nothing more, its
    OutputFile is discarded, and fusion's own sinks and the summary are complete."""
    from fusion.api import OutputFile

    class Failing:
        name = "failing"

        def __init__(self, path, when):
            self._out = OutputFile(path, "w")
            self.when, self.n = when, 0

        def on_estimate(self, estimate):
            self.n += 1
            if self.when == "estimate" and self.n == 3:
                raise RuntimeError("exploded")
            self._out.write(f"{estimate.t}\n")

        def close(self):
            if self.when == "close":
                raise OSError(28, "No space left on device")
            self._out.close()

    for when in ("estimate", "close"):
        path = tmp_path / f"{when}.txt"
        kept = pipeline.Collect()
        result = pipeline.run(load_system(EXAMPLE), load_system(EXAMPLE).recording, [Failing(path, when), kept])
        assert len(kept.estimates) == result.stats.estimates > 2000
        assert not path.exists() and os.listdir(tmp_path) == [], os.listdir(tmp_path)   # no cut file, no .tmp
        method = "on_estimate" if when == "estimate" else "close"
        assert result.plugin_errors[0].startswith("plugin sink 'failing': its ")  # no package: a test's class
        assert f"its {method}() raised" in result.plugin_errors[0] and f"its output {path} was discarded" in \
            result.plugin_errors[0], result.plugin_errors


def test_hooks_and_plugin_sinks_cannot_write_into_the_filter(capsys):
    """The estimate a hook or a plugin's sink is given is read-only: a hook that does estimate.belief.x[0] +=
    1000 would write into the filter's own state; the write raises
    in the plugin; a hook that only reads sees the same numbers as the run's own sinks."""
    class Mutating:
        @hookimpl
        def fusion_on_estimate(self, estimate):
            estimate.belief.x[0] += 1000.0

    _, registry = make_plugin_manager(extra_plugins=[Mutating()])
    system = load_system(EXAMPLE, registry=registry)
    mutated = pipeline.run(system, system.recording)
    assert re.search(r"fusion_on_estimate hook raised ValueError: .*read-only", mutated.plugin_errors[0])

    class PluginSink:                       # a sink defined outside fusion: gets read-only copies too
        def __init__(self):
            self.seen = []

        def on_estimate(self, estimate):
            assert not estimate.belief.x.flags.writeable
            self.seen.append(estimate.belief.x.copy())

        def close(self):
            pass

    mine, own = PluginSink(), pipeline.Collect()
    pipeline.run(load_system(EXAMPLE), load_system(EXAMPLE).recording, [own, mine])
    assert len(mine.seen) == len(own.estimates) > 2000
    assert all((a == e.belief.x).all() for a, e in zip(mine.seen, own.estimates))
    assert own.estimates[0].belief.x.flags.writeable          # fusion's own sinks: the run's objects


def test_no_hooks_when_none_is_implemented():
    system = load_system(EXAMPLE)
    run = pipeline.Run(system)
    assert run._hook_estimate is None and run._hook_event is None and run._hook_end is None


class Interrupting(Source):
    """Yields the first ``n`` lines of a recording, then behaves as if the user pressed Ctrl-C."""

    name = "interrupting"
    n = 1200

    def lines(self):
        for k, line in enumerate(open_lines(ROOT / "recordings" / "example_2d.log")):
            if k == self.n:
                raise KeyboardInterrupt
            yield line


def test_ctrl_c_writes_the_summary_of_what_was_read_and_exits_130(tmp_path, monkeypatch):
    import fusion.sources.select as select

    monkeypatch.setattr(select, "open_source", lambda spec, registry=None, **kw: Interrupting())
    out, csv = tmp_path / "s.json", tmp_path / "e.csv"
    assert main(["run", str(EXAMPLE), "-q", "--summary-json", str(out), "-o", str(csv)]) == 130
    s = json.loads(out.read_text())
    assert s["interrupted"] is True
    n_uwb = sum(",uwb," in ln for ln in list(open_lines(ROOT / "recordings" / "example_2d.log"))[:Interrupting.n])
    assert s["sensors"]["uwb"]["received"] == n_uwb and "errors" in s
    assert len(csv.read_text().splitlines()) == 1 + s["sensors"]["uwb"]["used"]  # every estimate kept on disk


class Failing(Source):
    """Yields the first ``n`` lines of a recording, then its link fails (``error``: what it raises)."""

    name = "failing"
    label = "flaky://bench"
    n = 1200
    error: BaseException = ConnectionResetError(104, "Connection reset by peer")

    def lines(self):
        for k, line in enumerate(open_lines(ROOT / "recordings" / "example_2d.log")):
            if k == self.n:
                raise self.error
            yield line


@pytest.mark.parametrize("error, text", [(ConnectionResetError(104, "Connection reset by peer"), "Connection reset"),
                                         (InputError("link lost"), "link lost")])
def test_a_source_that_fails_mid_run_ends_it_like_ctrl_c_with_exit_2(tmp_path, monkeypatch, capsys, error, text):
    """What was read is processed and summarised (--summary-json written, every estimate in the CSV), the
    run-end hook is called, and the one-line error names the source and what it raised."""
    import fusion.sources.select as select

    src = Failing()
    src.error = error
    monkeypatch.setattr(select, "open_source", lambda spec, registry=None, **kw: src)
    out, csv = tmp_path / "s.json", tmp_path / "e.csv"
    assert main(["run", str(EXAMPLE), "-q", "--summary-json", str(out), "-o", str(csv)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err
    assert f"the input stopped early: flaky://bench: {text}" in err
    s = json.loads(out.read_text())
    n_uwb = sum(",uwb," in ln for ln in list(open_lines(ROOT / "recordings" / "example_2d.log"))[:Failing.n])
    assert s["sensors"]["uwb"]["received"] == n_uwb and text in s["source_error"]
    assert len(csv.read_text().splitlines()) == 1 + s["sensors"]["uwb"]["used"]


def test_the_run_end_hook_sees_a_failed_source(tmp_path):
    watcher = Watcher()
    _, registry = make_plugin_manager(extra_plugins=[watcher])
    system = load_system(EXAMPLE, registry=registry)
    result = pipeline.run(system, Failing())
    assert result.source_error.startswith("flaky://bench: ") and watcher.ends == [result.summary]


def test_a_component_failure_is_still_an_internal_error_not_a_lost_source():
    """An OSError raised by a model (not by the source) is that message's failure, not 'the input stopped'."""
    system = load_system(EXAMPLE)
    sensor = system.sensors["uwb"]
    model = sensor.model

    class Boom(type(model)):
        def observe(self, message):
            raise OSError("disk on fire")

    model.__class__ = Boom
    result = pipeline.run(system, system.recording)
    assert result.source_error is None and "source_error" not in result.summary
    uwb = result.summary["sensors"]["uwb"]
    assert uwb["used"] == 0 and uwb["malformed"] == uwb["received"] > 1000   # each message's failure counted


def test_recording_beacons_the_config_lacks_or_places_elsewhere_are_warned_about(tmp_path, capsys):
    uwb = ROOT / "configs" / "uwb_pv_ukf.yaml"
    lines = (ROOT / "recordings" / "uwb_route1.log").read_text().splitlines()
    at = next(i for i, ln in enumerate(lines) if ln.startswith("# beacon B2"))
    lines[at] = "# beacon B2: 300 0 0"
    lines.insert(at + 1, "# beacon B5: 1 2 0")
    log = tmp_path / "moved.log"
    log.write_text("\n".join(lines) + "\n")
    out = tmp_path / "s.json"
    # a config contradicting its recording is refused (fusion.header_checks), naming both values ...
    assert main(["run", str(uwb), "--input", str(log), "--summary-json", str(out), "-o", str(tmp_path / "e.csv")]) == 2
    err = capsys.readouterr().err
    assert "beacons.B2: [30, 0] in the config, [300, 0, 0] in the recording" in err and "(and 1 more)" in err
    assert "moved.log:" in err and "prefer" in err and not out.exists()
    # ... unless it prefers its own: then the run warns
    preferring = tmp_path / "uwb.yaml"
    preferring.write_text(uwb.read_text().replace("../recordings/", str(ROOT / "recordings") + "/") + "\nprefer: config\n")
    uwb = preferring
    assert main(["run", str(uwb), "--input", str(log), "--summary-json", str(out), "-o", str(tmp_path / "e.csv")]) == 0
    err = capsys.readouterr().err
    assert "the recording declares beacon(s) B5 that the config does not define" in err
    assert "beacon B2 is at [300.0, 0.0, 0.0] in the recording's header and at [30.0, 0.0] in the config (270 m" in err
    assert json.loads(out.read_text())["events"]["warning"] == 2
    main(["run", str(uwb), "-q", "--summary-json", str(out), "-o", str(tmp_path / "e.csv"), "--force"])
    assert "warning" not in json.loads(out.read_text()).get("events", {})      # the shipped recording agrees


@pytest.mark.parametrize("fields, expect", [
    ("# fields truth x y vx vy", "truth columns x y are no element of the state, and the state's px py are not "
                                 "among the truth columns"),
    (None, "1357 truth line(s) but no '# fields truth ...' header line names their columns"),
    ("# fields truth px py vx vy", None),
])
def test_truth_that_cannot_be_compared_is_warned_about(tmp_path, fields, expect):
    uwb = ROOT / "configs" / "uwb_pv_ukf.yaml"
    lines = [ln for ln in (ROOT / "recordings" / "uwb_route1.log").read_text().splitlines()
             if not ln.startswith("# fields truth")]
    if fields:
        lines.insert(1, fields)
    log = tmp_path / "t.log"
    log.write_text("\n".join(lines) + "\n")
    notes = []
    result = pipeline.run(load_system(uwb), log, on_event=notes.append)
    warnings = [e.detail for e in notes if e.kind == "warning" and "truth" in e.detail]
    if expect is None:
        assert warnings == [] and result.summary["errors"]["position_rmse_m"] > 0
    else:
        assert len(warnings) == 1 and expect in warnings[0], warnings
        assert "position_rmse_m" not in result.summary.get("errors", {})


def test_extreme_decimator_is_bounded_and_keeps_the_largest():
    rng = np.random.default_rng(0)
    scores = rng.exponential(size=100_003)
    scores[77_777] = 1e6
    dec = ExtremeDecimator(max_points=500)
    for k, s in enumerate(scores):
        dec.add(k, float(s))
    items = dec.items()
    assert len(items) <= 502 and items == sorted(items)
    assert 77_777 in items and items[-1] == 100_002


def test_a_run_over_lines_and_a_spec_without_recording():
    spec = SystemSpec.model_validate({"name": "x", "process": {"type": "pv", "dims": 2}, "filter": "ekf",
                                      "beacons": {"B1": [0, 0], "B2": [10, 0], "B3": [0, 10]},
                                      "sensors": {"uwb": {"model": "range", "noise": 0.1}}})
    system = wire(spec)
    lines = ["0.0,uwb,B1,5.0\n", "0.1,uwb,B2,7.0\n", "0.2,uwb,B3,7.0\n", "0.3,,1\n"]
    result = pipeline.run(system, lines)
    assert result.summary["sensors"]["uwb"]["used"] == 3 and result.summary["sensors"]["?"]["malformed"] == 1
    assert result.summary["input"] == "<lines>" and result.last.t == pytest.approx(0.2)


def test_reference_lines_give_an_agreement_section_not_errors(tmp_path):
    """`reference` lines (another estimator's output) are compared like truth and labelled agreement."""
    lines = (ROOT / "recordings" / "example_2d.log").read_text().splitlines()
    out = []
    for ln in lines:
        out.append(ln)
        if ln.startswith("# fields truth"):
            out.append(ln.replace("truth", "reference", 1))
        elif ",truth," in ln:
            t, _, rest = ln.split(",", 2)
            vals = [float(v) for v in rest.split(",")]
            vals[0] += 0.5                                  # the other estimator is 0.5 m off in x
            out.append(f"{t},reference," + ",".join(repr(v) for v in vals))
    system = load_system(EXAMPLE)
    s = pipeline.run(system, [ln + "\n" for ln in out]).summary
    base = pipeline.run(system, system.recording).summary
    assert s["errors"] == base["errors"]                   # truth errors untouched by the reference
    ag = s["agreement"]
    assert "agreement" in ag["with"] and ag["samples"] == base["errors"]["samples"]
    assert ag["element_rmse"]["px"] == pytest.approx(math.sqrt(base["errors"]["element_rmse"]["px"] ** 2 + 0.25), rel=0.05)
    assert "reference" not in s["sensors"] and "reference" not in s.get("ignored_sensors", {})


def test_component_info_reaches_the_summary():
    """fusion.api.ReportsInfo: the nmea decoder's NED origin (paper 002) is written to the summary."""
    system = load_system(ROOT / "configs" / "imu_gps_mag_ekf.yaml")
    lines = (ROOT / "recordings" / "car_gps_mag.log").read_text().splitlines(True)[:6000]  # the static start
    s = pipeline.run(system, lines).summary
    gps = s["info"]["gps"]["decoder"]
    assert gps["origin_source"].startswith("mean of the fixes") and -90 <= gps["origin"]["lat_deg"] <= 90
    assert "info" not in pipeline.run(load_system(EXAMPLE), LINES_EXAMPLE).summary


LINES_EXAMPLE = (ROOT / "recordings" / "example_2d.log").read_text().splitlines(True)[:200]
