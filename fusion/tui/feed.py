"""The data side of the live view: lines -> iter_messages -> fusion.pipeline.Run, in a worker thread.

``LiveFeed.run()`` reads a source's lines (a recording paced by sensor time, or a live port), pushes the
messages through the scheduler and, at most ``refresh_hz`` times a second, hands an immutable
``FeedSnapshot`` (fusion.tui.snapshot) to ``post`` (the app posts it as a Textual message). A snapshot is cumulative (latest
estimate, counters, the last events and track points), so a newer one can always replace an older one:
a 100-200 Hz estimate stream costs the UI 10-20 refreshes a second.

Health (``fusion.tui.health``), the innovation histories (``fusion.tui.series``) and the state histories
(``fusion.tui.state_series``) are accumulated here too and ride in each snapshot. A reconnecting serial
source reports through ``source_status``.
With ``smooth_lag`` (s) the filter is recorded and a fixed-lag smoother (``fusion.smoothing.live``) gives
every estimate again ``smooth_lag`` s of sensor time later, smoothed on the measurements up to then: its
track and state histories ride in the snapshot beside the live ones (``smoothed``, ``smoothed_states``).

The UI thread only calls ``pause()``, ``resume()``, ``step()`` and ``stop()`` (thread-safe).
"""
from __future__ import annotations

import math
import threading
import time
from collections import deque
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

from fusion.api import Estimate, Event, InputError, Message
from fusion.config import System
from fusion.logformat import iter_messages
from fusion.pipeline import COUNTERS, Run, _guarded, _SourceLost, _source_message
from fusion.tui.health import Health, HealthMonitor
from fusion.tui.series import InnovationHistory
from fusion.tui.smoothed_trace import SmoothedTrace
from fusion.tui.snapshot import FeedSnapshot, LoggedEvent
from fusion.tui.state_series import StateHistory

__all__ = ["LiveFeed", "FeedSnapshot", "LoggedEvent", "COUNTERS"]
_SLICE = 0.05  # s: longest sleep between checks of pause/stop while pacing
IDLE_POST_S = 1.0  # s: a silent live source still gets a snapshot this often (its health, "no data for N s")
CAUGHT_UP_S = 0.5  # s without a line from a live source: everything it sent has been read (lag 0)


class LiveFeed:
    """Runs a system over a stream of lines in the calling (worker) thread.

    ``lines``: an iterable of text lines; ``live``: True for a device (never paced, never blocked by
    pause: pausing a live feed freezes only the view, so nothing the device sends is lost); ``speed``:
    replay rate against sensor time (0: as fast as possible); ``close``: called by stop() to wake a
    blocked reader (a serial source's close); ``sinks``: extra pipeline sinks (the ``--udp`` stream);
    ``expected_rates``/``limits``: per-sensor Hz and s for the health (fusion.tui.health); ``smooth_lag``:
    s of sensor time by which the fixed-lag smoothed trace follows the live one (None: none)."""

    def __init__(self, system: System, lines: Iterable[str], post: Callable[[FeedSnapshot], object], *,
                 source: str = "", live: bool = False, speed: float = 1.0, refresh_hz: float = 15.0,
                 close: Callable[[], object] | None = None, max_events: int = 500,
                 max_track: int = 4000, track_dt: float = 0.1, sinks: Sequence[Any] = (),
                 expected_rates: Mapping[str, float] | None = None, limits: Mapping[str, float] | None = None,
                 pause_at: float | None = None, smooth_lag: float | None = None):
        self.system = system
        self.smooth_lag = smooth_lag
        self.smoothed: SmoothedTrace | None = None
        if smooth_lag is not None:
            from fusion.smoothing.live import attach_fixed_lag

            system, lag_sink = attach_fixed_lag(system, smooth_lag, lambda est: self.smoothed.on_estimate(est))
            sinks = [*sinks, lag_sink]
        # The run keeps its statistics in bounded memory; the view's own histories are the deques below.
        self.run_ = Run(system, sinks, on_truth=self._take_truth, label=source)
        sensors = self.run_.scheduler.sensors
        self.health = HealthMonitor({n: s.role for n, s in sensors.items()}, expected_rates, limits)
        self.history = InnovationHistory({n: s.gate for n, s in sensors.items() if s.gate is not None})
        self.states = StateHistory(system.layout, lambda: self.parsed.header.fields.get("truth"))
        self.attempt = 0
        self.pause_at = pause_at
        self._step = threading.Event()
        self._stepping = False
        self.parsed = self.run_.parsed
        self.result = None  # the RunResult once the input has ended
        self._lines = lines
        self._post = post
        self.source = source
        self.live = live
        self.speed = max(0.0, float(speed))
        self.refresh_dt = 1.0 / refresh_hz if refresh_hz > 0 else 0.0
        self._close = close
        self._stop = threading.Event()
        self.done = threading.Event()   # set when run() has returned (the run finished, its hooks called)
        self._running = threading.Event()
        self._running.set()
        self.events: deque[LoggedEvent] = deque(maxlen=max_events)
        self._seq = 0
        self.track: deque[tuple[float, float]] = deque(maxlen=max_track)
        self.truth: deque[tuple[float, float]] = deque(maxlen=max_track)
        self.track_total = self.truth_total = 0
        self.track_dt = track_dt
        self._track_t = self._truth_t = -math.inf
        self.estimate: Estimate | None = None
        self.lines_read = 0
        self._emitted_lines = -1
        self._data_wall = time.monotonic()
        self.sensor_t = math.nan
        self.state = "waiting"
        self.message = ""
        self._next_post = 0.0
        self._last_post = -math.inf
        self._window: deque[tuple[float, float, dict[str, int]]] = deque()
        self._wall0: float | None = None
        self._t_first = math.nan
        self._t_start = math.nan  # time of the first message
        self._best_offset = math.inf  # a live feed: least (wall - stream time) so far (s), for lag_s
        lay = system.layout
        self._pos = None
        if "p" in lay and lay.block("p").size >= 2:
            start = lay["p"].start
            self._pos = (start, start + 1)
            self._pos_names = lay.block("p").element_names()[:2]
        if smooth_lag is not None:
            self.smoothed = SmoothedTrace(lay, lambda: self.parsed.header.fields.get("truth"), self._pos,
                                          max_track, track_dt)
        self._truth_idx: tuple[int, int] | None | bool = None

    # ------------------------------------------------------------------ control (any thread)
    def pause(self) -> None:
        self._running.clear()

    def resume(self) -> None:
        self._running.set()

    @property
    def paused(self) -> bool:
        return not self._running.is_set()

    @property
    def stepping(self) -> bool:
        """A single step of a paused replay is under way (its estimate not shown yet)."""
        return self._stepping

    def step(self) -> None:
        """While a replay is paused: read on to the next estimate, then hold again."""
        self._step.set()

    def source_status(self, state: str, attempt: int, detail: str) -> None:
        """Called by a reconnecting source in the reading thread: ``reconnecting`` (before attempt
        ``attempt``) or ``connected``."""
        if state == "reconnecting":
            if self.state != "reconnecting":
                self._log(Event(self.sensor_t, "source", None, f"port lost; reconnecting ({detail})"))
            self.state, self.attempt = "reconnecting", attempt
            self.message = f"attempt {attempt}: {detail}"
        else:
            self._log(Event(self.sensor_t, "source", None, f"port back after {attempt} attempt(s)"))
            self.state, self.attempt, self.message = "running", 0, ""
            # a reopened port holds no backlog: the lag is measured afresh from its first line (the device's
            # clock may have stopped or restarted while it was away; the gap is no lag of the view)
            self._best_offset = math.inf
        self._emit(time.monotonic())

    def stop(self) -> None:
        """Stop reading (returns at once; the worker ends within ~0.1 s)."""
        self._stop.set()
        self._running.set()
        if self._close is not None:
            self._close()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def idle(self) -> None:
        """Called by a live source in the reading thread when a read timed out: shows what is pending, and
        at least every IDLE_POST_S the health of a port that stays silent (LOST after its silent_s, from the
        port's opening when it never sent a byte)."""
        now = time.monotonic()
        if now - self._last_post >= IDLE_POST_S:
            self._next_post = 0.0
            self._emit(now)
        else:
            self._maybe_emit(now)

    # ------------------------------------------------------------------ the worker
    def run(self) -> FeedSnapshot:
        """Read until the end of the input, a lost port, or stop(); returns the final snapshot. The run is
        finished (``result``; its sinks closed, ``fusion_on_run_end`` called) however reading ended: at the
        end of the input, a lost source (``source_error``), or ``stop()`` (``q``: ``interrupted``, as Ctrl-C
        in ``fusion run``; a live session can end no other way); not after an internal error."""
        try:
            return self._run()
        finally:
            self.done.set()

    def _run(self) -> FeedSnapshot:
        run = self.run_
        self._emit(time.monotonic())
        ended = False
        source_error = None
        try:
            self.state = "running"
            for item in iter_messages(self._paced(_guarded(self._lines)), self.parsed):
                if isinstance(item, Message) and item.t - item.t == 0.0:
                    if self.sensor_t != self.sensor_t:
                        self._t_start = item.t
                    self.sensor_t = item.t
                    self.health.on_message(item)
                    if self.pause_at is not None and item.t >= self.pause_at and not self.live:
                        self.pause_at = None
                        self._running.clear()  # held before the next line (pictures at fixed replay times)
                for out in run.push(item):
                    self._take(out)
                now = time.monotonic()
                if now >= self._next_post:
                    self._emit(now)
            ended = not self._stop.is_set()
            self.state = "finished" if ended else "stopped"
        except (InputError, _SourceLost) as exc:  # a port that vanished, a source's lost link: keep the last state
            ended = True
            self.state = "lost"
            cause = exc.__cause__ if isinstance(exc, _SourceLost) and exc.__cause__ is not None else exc
            self.message = source_error = _source_message(self.source, cause) if self.source else str(cause)
            self._log(Event(self.sensor_t, "source", None, self.message))
        except Exception as exc:  # a bug: report it in the view rather than killing the app
            self.state = "error"
            self.message = f"internal error: {type(exc).__name__}: {exc}"
            self._log(Event(self.sensor_t, "error", None, self.message))
        if self.state != "error":
            try:
                if ended:
                    for out in run.scheduler_finish():
                        self._take(out)
                self.result = run.finish(interrupted=not ended, source_error=source_error)
            except Exception as exc:
                self.state = "error"
                self.message = f"internal error: {type(exc).__name__}: {exc}"
                self._log(Event(self.sensor_t, "error", None, self.message))
        else:
            try:
                run.close_sinks()  # the --udp socket is released too
            except Exception:  # a sink that fails to close must not hide how the run ended
                pass
        return self._emit(time.monotonic())

    def _paced(self, lines: Iterable[str]) -> Iterator[str]:
        """The lines, counted; a replay is held while paused and paced by sensor time at ``speed``.

        Paced by the stream's time as the scheduler keeps it (``Scheduler.newest``, after the clock
        guard), not by raw stamps: a line stamped farther than the guard's ``future_s`` from the stream's
        time (a wild stamp, which the guard drops, or a clock jump, which it re-synchronises) is not
        waited for; the stream's time only moves on when the scheduler accepts it. And no single wait is
        longer than ``scheduler.max_predict_s`` / speed (the longest gap the scheduler predicts over): a
        longer one is cut, with a ``replay`` event (one stamp 100,000 s ahead would otherwise freeze the
        view for hours)."""
        t0 = wall0 = None
        sched = self.run_.scheduler
        future = sched.clock.future_s
        cap = sched.max_predict
        paced = -math.inf   # the stream time paced to so far
        for raw in lines:
            if self._stop.is_set():
                return
            self.lines_read += 1
            self._data_wall = time.monotonic()
            if not self.live:
                if not self._running.is_set() and not self._stepping:
                    held = self._hold()
                    if wall0 is not None:
                        wall0 += held
                if self._stepping:
                    t0 = None  # a single step is not paced; pacing restarts from the next line
                elif self.speed > 0.0:
                    t = _time_of(raw)
                    if t is not None:
                        base = sched.newest
                        if base == -math.inf:
                            base = t if t0 is None else paced
                        t = t if abs(t - base) <= future else base   # far from the stream: not waited for
                        if t0 is None or t < paced - future:        # the start, or the stream's time went back
                            t0, wall0, paced = t, time.monotonic(), t
                        elif t > paced:
                            if t - paced > cap:
                                self._log(Event(paced, "replay", None, f"{t - paced:.3g} s of sensor time to the "
                                                f"next message: waited {cap:g} s / speed at most "
                                                "(scheduler.max_predict_s)"))
                                t0 += t - paced - cap  # type: ignore[operator]  # (the origin moves on)
                            paced = t
                            wall0 += self._sleep_until(wall0 + (t - t0) / self.speed)  # type: ignore[operator]
            if self._stop.is_set():
                return
            yield raw

    def _hold(self) -> float:
        """Wait while paused; returns the seconds waited."""
        start = time.monotonic()
        if self.lines_read:
            self._emit(start)  # the view shows where the replay stopped
        while not self._running.wait(_SLICE):
            if self._step.is_set():
                self._step.clear()
                self._stepping = True
                break
        return time.monotonic() - start

    def _sleep_until(self, target: float) -> float:
        """Sleep until ``target`` (monotonic) in slices; returns the time spent paused (shifts the pacing)."""
        held = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            self._maybe_emit(now)
            if not self._running.is_set() and not self._stepping:
                h = self._hold()
                held += h
                target += h
                continue
            left = target - now
            if left <= 0.0:
                break
            time.sleep(min(left, _SLICE, max(self._next_post - now, 0.001)))
        return held

    # ------------------------------------------------------------------ bookkeeping
    def _take(self, out: Estimate | Event) -> None:
        if isinstance(out, Estimate):
            self.estimate = out
            self.health.on_estimate(out)
            self.history.on_estimate(out)
            self.states.on_estimate(out)
            if self._stepping:
                self._stepping = False
                self._next_post = 0.0  # show the step at once

            if self._pos is not None and out.t - self._track_t >= self.track_dt:
                x = out.belief.x
                self.track.append((float(x[self._pos[0]]), float(x[self._pos[1]])))
                self.track_total += 1
                self._track_t = out.t
        else:
            self._log(out)

    def _take_truth(self, msg: Message) -> None:
        """A truth line: its (north, east) point goes to the view's true track (decimated by time), the
        whole line to the state errors."""
        self.states.on_truth(msg)
        if self.smoothed is not None:
            self.smoothed.on_truth(msg)
        if self._truth_idx is None and self._pos is not None:
            names = self.parsed.header.fields.get("truth")
            ok = names is not None and all(n in names for n in self._pos_names)
            self._truth_idx = (names.index(self._pos_names[0]), names.index(self._pos_names[1])) if ok else False
        if self._truth_idx:
            i, j = self._truth_idx  # type: ignore[misc]
            if msg.t - self._truth_t >= self.track_dt and len(msg.values) > max(i, j):
                try:
                    self.truth.append((float(msg.values[i]), float(msg.values[j])))
                except (TypeError, ValueError):
                    return
                self.truth_total += 1
                self._truth_t = msg.t

    def _log(self, ev: Event) -> None:
        if ev.kind == "clock":   # a sensor re-synchronised: the stream's time base moved, the lag restarts
            self._best_offset = math.inf
        self.health.on_event(ev)
        self._seq += 1
        self.events.append(LoggedEvent(self._seq, ev.t, ev.kind, ev.sensor, ev.detail))

    def counters(self) -> dict[str, dict[str, int]]:
        """Counters by sensor as ``fusion run`` reports them (the run's own statistics)."""
        return self.run_.stats.counters()

    def _maybe_emit(self, now: float) -> None:
        """Emit when due and something new was read since the last snapshot."""
        if now >= self._next_post and self.lines_read != self._emitted_lines:
            self._emit(now)

    def _emit(self, now: float) -> FeedSnapshot:
        counters = self.counters()
        received = {k: v["received"] for k, v in counters.items()}
        t = self.sensor_t
        if self._wall0 is None and t == t:
            self._wall0, self._t_first = now, t
        win = self._window
        win.append((now, t, received))
        while len(win) > 2 and now - win[1][0] >= 1.0:
            win.popleft()
        w0, t0, r0 = win[0]
        ratio, rates = math.nan, {}
        active = self.state in ("running", "waiting", "reconnecting")
        if active and now - w0 > 0.2 and t0 == t0:
            ratio = (t - t0) / (now - w0)
        elif self._wall0 is not None and now > self._wall0:
            ratio = (t - self._t_first) / (now - self._wall0)
        if not active and t - self._t_start > 0.0:
            rates = {k: n / (t - self._t_start) for k, n in received.items()}  # the run's mean
        elif t == t:
            rates = {k: v for k, v in self.health.rates(t).items() if v == v}  # by sensor time: deterministic
        snap = FeedSnapshot(
            lag_s=self._lag(now), source=self.source, live=self.live, state=self.state, estimate=self.estimate, counters=counters,
            ignored=self.run_.stats.ignored(), rates=rates, events=tuple(self.events), track=tuple(self.track),
            track_total=self.track_total, truth=tuple(self.truth), truth_total=self.truth_total,
            lines=self.lines_read, data_wall=self._data_wall, sensor_t=t, speed_ratio=ratio, wall=now, message=self.message,
            health=self._assess(t, rates, counters, now, active), series=self.history.snapshot(), attempt=self.attempt,
            states=self.states.snapshot(), smooth_lag=self.smooth_lag,
            **self._smoothed_fields())
        self._next_post = now + self.refresh_dt
        self._last_post = now
        self._emitted_lines = self.lines_read
        self._post(snap)
        return snap

    def _lag(self, now: float) -> float:
        """A live feed: how far behind the device the view is (s), the wall clock's lead on the stream's time
        (the scheduler's, after the clock guard) beyond its least so far, i.e. what the view fell behind
        since it was best caught up; 0 once nothing has been read for CAUGHT_UP_S (all read is fused);
        NaN for a replay or before a message."""
        if not self.live or self.state != "running":
            return math.nan
        newest = self.run_.scheduler.newest
        if newest == -math.inf:
            return math.nan
        offset = now - newest
        if offset < self._best_offset:
            self._best_offset = offset
        return 0.0 if now - self._data_wall > CAUGHT_UP_S else offset - self._best_offset

    def _smoothed_fields(self) -> dict:
        if self.smoothed is None:
            return {}
        track, total, states = self.smoothed.snapshot()
        return {"smoothed": track, "smoothed_total": total, "smoothed_states": states}

    def _assess(self, t: float, rates: dict[str, float], counters: dict[str, dict[str, int]], now: float,
                active: bool) -> Health:
        sched = self.run_.scheduler
        repairs = int(self.run_.stats.filter_counters.get("not_positive_definite", 0))
        return self.health.assess(t, rates, counters, self.state, silent_wall_s=now - self._data_wall, live=self.live,
                                  estimate=self.estimate, repairs=repairs, resets=sched.resets, message=self.message,
                                  rate_valid=active)


def _time_of(raw: str) -> float | None:
    """Sensor time of a message line (None for comments, blanks and lines without a time)."""
    head = raw.split(",", 1)[0]
    try:
        t = float(head)
    except ValueError:
        return None
    return t if t - t == 0.0 else None
