"""Microseconds per predict and per update of every filter, beside FilterPy, measured in the same run.

    python benchmarks/bench_filters.py                  # the table (4-state constant velocity + 4 ranges)
    python benchmarks/bench_filters.py --steps 1000 --rounds 10 --clock cpu

Every filter (and FilterPy's UnscentedKalmanFilter with MerweScaledSigmaPoints of the same alpha, beta,
kappa, and FilterPy's KalmanFilter with the Jacobians frozen at x0, as a floor) runs the same loop of
``predict(dt)`` and of ``update(z)``. The runners are interleaved round by round and each keeps its
best round, so a busy machine slows all of them alike; the ratio column is FilterPy's UKF time per
predict + update over ours.

The 16-state INS (``ins`` process + ``position`` fix) runs too when those plugins are installed. To add
a model call :func:`bench_model` with its process and measurement models, x0, P0, u (or None), z, R and
dt; see :func:`cv_range_model`, :func:`ins_position_model` and ``main``. FilterPy gets the process
noise ``Q(x, u, dt)`` at its prior mean before each predict, as our filters evaluate it.
"""
from __future__ import annotations

import argparse
import gc
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from fusion import testing
from fusion.registry import default_registry


@dataclass
class Runner:
    name: str
    predict: Callable[[], None]     # runs `steps` predicts
    update: Callable[[], None]      # runs `steps` updates
    overhead: Callable[[], None] | None = None  # loop overhead to subtract from update (FilterPy resets)
    best: dict = field(default_factory=lambda: {"predict": float("inf"), "update": float("inf"),
                                                "overhead": float("inf")})


CLOCKS = {"wall": time.perf_counter, "cpu": time.thread_time}
_clock = time.perf_counter


def _time(fn) -> float:
    t0 = _clock()
    fn()
    return _clock() - t0


def our_runner(flt, process, model, x0, P0, u, z, R, dt, steps) -> Runner:
    b0 = flt.initial_belief(0.0, x0, P0)
    prior = flt.predict(b0, process, u, dt)

    def predict():
        b = b0
        for _ in range(steps):
            b = flt.predict(b, process, u, dt)

    def update():
        for _ in range(steps):
            flt.update(prior, model, z, R)

    return Runner(flt.name + _label(flt), predict, update)


def _label(flt) -> str:
    p = flt.params.model_dump()
    shown = {k: p[k] for k in ("linear_prediction", "zeroth_point") if k in p}
    if "max_iterations" in p:
        shown["max_iterations"] = p["max_iterations"]
    return "" if not shown else " " + ",".join(f"{k}={v}" for k, v in shown.items())


def filterpy_ukf_runner(process, model, x0, P0, u, z, R, dt, steps, alpha, beta, kappa) -> Runner:
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    n, m = x0.shape[0], z.shape[0]
    ukf = UnscentedKalmanFilter(n, m, dt, model.h, lambda x, dt: process.f(x, u, dt),
                                MerweScaledSigmaPoints(n, alpha, beta, kappa))
    ukf.Q, ukf.R = process.Q(x0, u, dt), R
    ukf.x, ukf.P = x0.copy(), P0.copy()
    ukf.predict()
    x1, P1, sig = ukf.x.copy(), ukf.P.copy(), ukf.sigmas_f.copy()

    def predict():  # Q(x, u, dt) at the prior mean each step, as our filters do (state-dependent Q)
        ukf.x, ukf.P = x0.copy(), P0.copy()
        for _ in range(steps):
            ukf.Q = process.Q(ukf.x, u, dt)
            ukf.predict()

    def update():  # from the same prior each time, as ours
        for _ in range(steps):
            ukf.x, ukf.P, ukf.sigmas_f = x1.copy(), P1.copy(), sig
            ukf.update(z)

    def overhead():
        for _ in range(steps):
            ukf.x, ukf.P, ukf.sigmas_f = x1.copy(), P1.copy(), sig

    return Runner(f"FilterPy UnscentedKalmanFilter", predict, update, overhead)


def filterpy_kf_runner(process, model, x0, P0, u, z, R, dt, steps) -> Runner:
    from filterpy.kalman import KalmanFilter

    n, m = x0.shape[0], z.shape[0]
    kf = KalmanFilter(n, m)
    F = process.jacobian(x0, u, dt)
    kf.F = np.eye(n) if F is None else F
    kf.Q, kf.R, kf.H = process.Q(x0, u, dt), R, np.atleast_2d(model.jacobian(x0))
    kf.x, kf.P = x0.copy(), P0.copy()
    kf.predict()
    x1, P1 = kf.x.copy(), kf.P.copy()

    def predict():
        kf.x, kf.P = x0.copy(), P0.copy()
        for _ in range(steps):
            kf.predict()

    def update():
        for _ in range(steps):
            kf.x, kf.P = x1.copy(), P1.copy()
            kf.update(z)

    def overhead():
        for _ in range(steps):
            kf.x, kf.P = x1.copy(), P1.copy()

    return Runner("FilterPy KalmanFilter (F, H frozen)", predict, update, overhead)


def bench_model(title, process, model, x0, P0, u, z, R, dt, filters=None, steps=250, rounds=30,
                alpha=0.5, beta=2.0, kappa=0.0, out=print):
    """Time the filters (a list of (registry name, params)) and FilterPy on one model; print a table.

    Returns ``{label: (us_predict, us_update)}``."""
    reg = default_registry()
    if filters is None:
        filters = [(name, {}) for name in reg.names("filter")]
    runners: list[Runner] = []
    for name, params in filters:
        cls = reg.get("filter", name)
        if name in ("ukf", "srukf"):
            params = {"alpha": alpha, "beta": beta, "kappa": kappa, **params}
        flt = cls(cls.Params(**params))
        try:
            runners.append(our_runner(flt, process, model, x0, P0, u, z, R, dt, steps))
        except Exception as exc:  # e.g. kf on a non-linear process
            out(f"  {name}: skipped ({type(exc).__name__}: {exc})")
    ref = filterpy_ukf_runner(process, model, x0, P0, u, z, R, dt, steps, alpha, beta, kappa)
    runners.append(ref)
    if process.jacobian(x0, u, dt) is not None and model.jacobian(x0) is not None:
        runners.append(filterpy_kf_runner(process, model, x0, P0, u, z, R, dt, steps))
    gc_was = gc.isenabled()
    gc.disable()
    try:
        for r in runners:  # warm-up
            r.predict(), r.update()
        for _ in range(rounds):
            for r in runners:
                r.best["predict"] = min(r.best["predict"], _time(r.predict))
                r.best["update"] = min(r.best["update"], _time(r.update))
                if r.overhead is not None:
                    r.best["overhead"] = min(r.best["overhead"], _time(r.overhead))
    finally:
        if gc_was:
            gc.enable()

    def per_call(r):
        over = r.best["overhead"] if r.overhead is not None else 0.0
        return r.best["predict"] / steps * 1e6, (r.best["update"] - over) / steps * 1e6

    ref_step = sum(per_call(ref))
    out(f"\n{title}: n={x0.shape[0]}, m={z.shape[0]}, alpha={alpha}, beta={beta}, kappa={kappa}; "
        f"{steps} calls a round, best of {rounds} rounds")
    out(f"{'filter':68s} {'predict us':>10s} {'update us':>10s} {'step us':>9s} {'FilterPy UKF/ours':>18s}")
    table = {}
    for r in runners:
        p, u_ = per_call(r)
        table[r.name] = (p, u_)
        out(f"{r.name:68s} {p:10.1f} {u_:10.1f} {p + u_:9.1f} {ref_step / (p + u_):17.1f}x")
    return table


def cv_range_model():
    """4-state 2-D constant velocity (p:2 v:2, paper 001 eqs. 3-4) + ranges to 4 beacons (eq. 6)."""
    process = testing.ConstantVelocity(testing.ConstantVelocity.Params(dims=2, q=0.5))
    model = testing.RangeMeasurement(testing.RangeMeasurement.Params(
        beacons=[[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]], n=4))
    x0 = np.array([5.0, 4.0, 1.0, 0.5])
    P0 = np.diag([0.5, 0.5, 0.1, 0.1])
    R = np.eye(4) * 0.05 ** 2
    z = model.h(x0 + np.array([0.05, -0.03, 0.0, 0.0]))
    return process, model, x0, P0, None, z, R, 0.1


def shipped_uwb_model(config: str = "configs/uwb_pv_ukf.yaml"):
    """The shipped plugins as a user runs them: ``pv`` and ``range`` exactly as configured in
    ``configs/uwb_pv_ukf.yaml`` (paper 001), one range to one beacon per update, dt = the range period."""
    from pathlib import Path

    from fusion.config import load_system

    system = load_system(Path(__file__).resolve().parents[1] / config)
    process = system.process
    sensor = next(s for s in system.sensors.values() if s.model is not None)
    x0 = system.x0.copy()
    x0[process.layout["p"]] = [5.0, 4.0]
    x0[process.layout["v"]] = [1.0, 0.5]
    P0 = np.diag([0.5, 0.5, 0.1, 0.1])
    beacon = next(iter(system.beacons))
    obs = sensor.model.observe(__import__("fusion.api", fromlist=["Message"]).Message(0.0, "uwb", (beacon, 5.0)))
    model = obs.model
    z = model.h(x0 + np.array([0.05, -0.03, 0.0, 0.0]))
    return process, model, x0, P0, None, z, sensor.R, 0.05


def ins_position_model():
    """16-state strapdown INS (``ins`` plugin, paper 000 eqs. 33-52, IMU input u) + position fix with
    lever arm (``position`` plugin, eq. 53); None when those plugins are not installed."""
    from fusion.api import BuildContext

    reg = default_registry()
    if "ins" not in reg.names("process") or "position" not in reg.names("measurement"):
        return None
    process = testing.build("process", "ins", {"quat_norm_variance": 1e-12})
    model = testing.build("measurement", "position", {"lever_arm": (0.2, 0.0, -0.1)},
                          BuildContext(layout=process.layout))
    c, s = np.cos(0.15), np.sin(0.15)
    x0 = process.layout.vector({"p": [1.0, 2.0, 0.0], "v": [0.5, 0.1, 0.0], "q": [c, 0.0, 0.0, s]})
    P0 = np.diag([0.1] * 3 + [0.05] * 3 + [1e-3] * 4 + [1e-3] * 3 + [1e-5] * 3)
    u = np.array([0.1, -0.05, -9.78, 0.01, -0.02, 0.05])
    z = model.h(x0) + np.array([0.03, -0.02, 0.01])
    return process, model, x0, P0, u, z, np.eye(3) * 0.05 ** 2, 0.01


FILTERS_4 = [
    ("kf", {}), ("ekf", {}), ("iekf", {}),
    ("ukf", {}), ("ukf", {"linear_prediction": "never"}),
    ("srukf", {}), ("srukf", {"zeroth_point": "cholupdate"}),
    ("srukf", {"linear_prediction": "never"}),
    ("srukf", {"linear_prediction": "never", "zeroth_point": "cholupdate"}),
]


FILTERS_16 = [
    ("ekf", {}), ("iekf", {}), ("ukf", {}), ("srukf", {}), ("srukf", {"zeroth_point": "cholupdate"}),
]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=250, help="calls a round (default 250)")
    ap.add_argument("--rounds", type=int, default=30, help="rounds; each runner keeps its best (default 30)")
    ap.add_argument("--alpha", type=float, default=0.5)
    ap.add_argument("--clock", choices=sorted(CLOCKS), default="wall",
                    help="wall: perf_counter (default); cpu: this thread's CPU time, steadier on a busy machine")
    args = ap.parse_args(argv)
    global _clock
    _clock = CLOCKS[args.clock]
    process, model, x0, P0, u, z, R, dt = cv_range_model()
    bench_model("4-state constant velocity + ranges to 4 beacons", process, model, x0, P0, u, z, R, dt,
                FILTERS_4, steps=args.steps, rounds=args.rounds, alpha=args.alpha)
    process, model, x0, P0, u, z, R, dt = shipped_uwb_model()
    bench_model("shipped plugins: pv + range as in configs/uwb_pv_ukf.yaml (one range a step)", process, model,
                x0, P0, u, z, R, dt, [("ekf", {}), ("ukf", {}), ("srukf", {})], steps=args.steps,
                rounds=args.rounds, alpha=args.alpha)
    ins = ins_position_model()
    if ins is not None:
        process, model, x0, P0, u, z, R, dt = ins
        bench_model("16-state INS (ins) + position fix (position)", process, model, x0, P0, u, z, R, dt,
                    FILTERS_16, steps=max(1, args.steps // 4), rounds=args.rounds, alpha=args.alpha)


if __name__ == "__main__":
    main()
