"""Small models for the smoother tests: a non-linear pendulum-like process and a unicycle driven by
inputs (speed, turn rate), vectorised over leading axes like the plugins."""
from __future__ import annotations

import numpy as np

from fusion.api import Belief, Estimate, Params, ProcessModel, StateLayout
from fusion.smoothing.backward import smooth, smoothed_estimates
from fusion.smoothing.record import ForwardLog, RecordingFilter
from fusion.smoothing.store import ChunkStore
from fusion_plugins.filters.rts import backend_for


class Swing(ProcessModel):
    """x = [a, w]: a' = a + w dt, w' = w - 2 sin(a) dt (a non-linear oscillator); Q diagonal."""

    name = "test_swing"

    class Params(Params):
        q: float = 0.05

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self.layout = StateLayout.parse("a:1 w:1")

    def f(self, x, u, dt):
        x = np.asarray(x, dtype=float)
        a, w = x[..., 0], x[..., 1]
        return np.stack([a + w * dt, w - 2.0 * np.sin(a) * dt], axis=-1)

    def jacobian(self, x, u, dt):
        return np.array([[1.0, dt], [-2.0 * np.cos(x[0]) * dt, 1.0]])

    def Q(self, x, u, dt):
        return np.diag([1e-4, self.params.q * dt])


class Unicycle(ProcessModel):
    """x = [px, py, th] driven by u = [speed, turn rate]: p' = p + s dt (cos th, sin th), th' = th + r dt."""

    name = "test_unicycle"
    input_dim = 2

    class Params(Params):
        q: float = 0.02

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self.layout = StateLayout.parse("p:2 th:1")

    def f(self, x, u, dt):
        x = np.asarray(x, dtype=float)
        th = x[..., 2]
        return np.stack([x[..., 0] + u[0] * dt * np.cos(th), x[..., 1] + u[0] * dt * np.sin(th),
                         th + u[1] * dt], axis=-1)

    def jacobian(self, x, u, dt):
        th = x[2]
        return np.array([[1.0, 0.0, -u[0] * dt * np.sin(th)], [0.0, 1.0, u[0] * dt * np.cos(th)], [0, 0, 1.0]])

    def Q(self, x, u, dt):
        return np.diag([self.params.q * dt, self.params.q * dt, 0.01 * dt])


class UnicycleRunNoise(Unicycle):
    """The unicycle with InputRunNoise: the sigma-point filters batch its runs of input samples (one draw
    of points), with Q of the interval at the predicted mean and the mean input."""

    name = "test_unicycle_run_noise"

    def Q_inputs(self, x0, x1, us, dts):
        return self.Q(x1, np.mean(us, axis=0), float(np.sum(dts)))


def smooth_sequence(flt, process, steps, x0, P0, chunk=1024, disk=None):
    """Run ``flt`` (recorded) over ``steps``: each ``(kind, args)`` with kind ``predict`` (u, dt),
    ``inputs`` (us, dts) or ``update`` (model, z, R); an estimate is noted after every step (``call``:
    ``args()`` is called, e.g. to switch a fault on; nothing is noted). Returns (filtered beliefs,
    smoothed beliefs) at the noted estimates."""
    log = ForwardLog(backend_for(flt), len(x0), chunk=chunk, disk=disk)
    rec = RecordingFilter(flt, log)
    b = rec.initial_belief(0.0, x0, P0)
    filtered = [b]
    log.note_estimate(Estimate(b.t, b, "output"))
    for kind, args in steps:
        if kind == "call":
            args()
            continue
        if kind == "predict":
            b = rec.predict(b, process, *args)
        elif kind == "inputs":
            b = rec.predict_inputs(b, process, *args)
        else:
            b = rec.update(b, *args).belief
        filtered.append(b)
        log.note_estimate(Estimate(b.t, b, "update" if kind == "update" else "output"))
    out = ChunkStore(chunk, disk)
    smooth(log, process.normalize, np.subtract, out)
    smoothed = [e.belief for e in smoothed_estimates(out, log.sqrt, log.sensors)]
    on_disk = log.bytes_on_disk + out.bytes_on_disk
    log.close()
    out.close()
    return filtered, smoothed, on_disk


def cov(b: Belief) -> np.ndarray:
    return b.P if b.P is not None else b.S @ b.S.T
