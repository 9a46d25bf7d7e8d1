"""The project's filters beside FilterPy, Stone Soup, navlie and dynamax, in one process; writes
benchmarks/results/peers.md.

    python benchmarks/bench_peers.py                   # ~3-5 min
    python benchmarks/bench_peers.py --quick           # smoke test (seconds)
    python benchmarks/bench_peers.py --peers filterpy  # only some peers (the others are listed as skipped)

Each peer steps its own plain-numpy model (benchmarks/peer_models.py), the project its own model
objects, on the same x0, P0, Q, R, measurements and sigma-point parameters (alpha 0.5, beta 2, kappa 0).
Before anything is timed, every peer's estimates are compared with the project's over a run of steps
(max |dx| in units of the posterior sd, and max |dP| / max |P|); a figure over its tolerance stops the
benchmark with exit status 1. Timing: BLAS single-threaded (set before numpy is imported), garbage
collection off, runners interleaved round by round from a fresh filter each round, the median round of
process CPU time (all threads: JAX's too) and of wall time.
"""
from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")
os.environ.setdefault("JAX_ENABLE_X64", "1")      # dynamax in float64, as every other filter here
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import argparse  # noqa: E402
import gc  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import peer_batch as pbt  # noqa: E402
import peer_models as pm  # noqa: E402
from peer_report import environment, write_page  # noqa: E402

PEERS = ("filterpy", "stonesoup", "navlie", "dynamax")
MODULE = {"filterpy": "filterpy.kalman", "stonesoup": "stonesoup.updater.kalman", "navlie": "navlie",
          "dynamax": "dynamax.nonlinear_gaussian_ssm"}
ALPHA, BETA, KAPPA = 0.5, 2.0, 0.0
EXACT_TOL = 1e-8       # same algorithm in float64: differences are rounding (~1e-12 seen)
DYNAMAX_TOL = 1e-4     # dynamax's psd_solve adds 1e-9 I to S each update: ~1e-6 after 50 steps
CONFIG = "configs/abps_ins.yaml"


class AgreementError(RuntimeError):
    pass


def available(wanted: list[str]) -> tuple[list[str], dict[str, str]]:
    """The peers that import, and why each other one is skipped."""
    import importlib

    ok, skipped = [], {}
    for name in PEERS:
        if name not in wanted:
            skipped[name] = "not asked for (--peers)"
            continue
        try:
            importlib.import_module(MODULE[name])
            ok.append(name)
        except Exception as exc:  # noqa: BLE001 - any import failure is a reason to skip
            skipped[name] = f"`import {MODULE[name]}` fails: {type(exc).__name__}: {exc}"
    if "navlie" in ok:
        ok.remove("navlie")
        skipped["navlie"] = "imports, but no navlie model is written in this benchmark yet"
    return ok, skipped


def agreement(ref, other) -> float:
    """max |x - x_ref| / sd_ref and max |P - P_ref| / max |P_ref| (the larger) between two final estimates."""
    (xr, Pr), (xo, Po) = ref, other
    sd = np.sqrt(np.einsum("...ii->...i", Pr))
    return float(max(np.max(np.abs(xo - xr) / sd), np.max(np.abs(Po - Pr)) / np.max(np.abs(Pr))))


def check(row: str, name: str, fig: float, tol: float, out: list) -> None:
    out.append((row, name, fig, tol))
    if not fig <= tol:
        raise AgreementError(f"agreement check failed: {name} against the project's filter on '{row}': "
                             f"{fig:.2e} > tolerance {tol:.0e} (the same inputs should give the same estimates)")


def run_steps(make, zs):
    step, estimate = make()
    for z in zs:
        step(z)
    return estimate()


def interleave(runners: dict, rounds: int) -> dict[str, tuple[float, float]]:
    """runners: name -> (make, run(made), count). Median (CPU s, wall s) per count over the rounds."""
    cpu = {k: [] for k in runners}
    wall = {k: [] for k in runners}
    gc_was = gc.isenabled()
    gc.disable()
    try:
        for make, run, _ in runners.values():
            run(make())
        for _ in range(rounds):
            for k, (make, run, count) in runners.items():
                made = make()
                c0, w0 = time.process_time(), time.perf_counter()
                run(made)
                cpu[k].append((time.process_time() - c0) / count)
                wall[k].append((time.perf_counter() - w0) / count)
                del made
            gc.collect()
    finally:
        if gc_was:
            gc.enable()
    return {k: (statistics.median(cpu[k]), statistics.median(wall[k])) for k in runners}


def stepper(make, zs):
    return (make, lambda made: [made[0](z) for z in zs], len(zs))


def cv_problem(d: int, K: int, seed: int = 1):
    """The d-axis constant-velocity + 4 ranges problem: the project's models, the plain ones, inputs."""
    from fusion import testing

    rng = np.random.default_rng(seed)
    beacons = pbt.BEACONS if d == 2 else rng.uniform(0.0, 20.0, (4, d))
    n, dt, q = 2 * d, 0.1, 0.5
    x0 = np.concatenate((np.full(d, 5.0), np.full(d, 0.5)))
    x0[:2] = [5.0, 4.0]
    P0 = np.diag([0.5] * d + [0.1] * d)
    R = np.eye(4) * 0.05 ** 2
    F, Q = pm.cv_matrices(d, q, dt)
    zs, x = [], x0.copy()
    for _ in range(K):
        x = F @ x
        zs.append(pm.ranges(x, beacons) + rng.normal(0, 0.05, 4))
    # The model's arithmetic is written for any number of axes; its Params cap dims at 3 for configs, so
    # the larger states of the scaling rows are built without that validation.
    process = testing.ConstantVelocity(testing.ConstantVelocity.Params.model_construct(dims=d, q=q,
                                                                                      analytic_jacobian=True))
    model = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=beacons.tolist(), n=n))
    return dict(n=n, dt=dt, x0=x0, P0=P0, R=R, F=F, Q=Q, zs=zs, beacons=beacons, process=process, model=model)


def cv_rows(n: int, peers: list[str], args, agree: list, r_scale: float) -> dict[str, tuple[float, float]]:
    """us per predict + update (CPU, wall) of each filter on the n-state problem."""
    p = cv_problem(n // 2, args.steps)
    b, F, Q, R, x0, P0, dt = p["beacons"], p["F"], p["Q"], p["R"], p["x0"], p["P0"], p["dt"]
    Rp = R * r_scale
    makers = {f"fusion {f}": (lambda f=f: pm.fusion_single(f, p["process"], p["model"], x0, P0, None, R, dt,
                                                            ALPHA, BETA, KAPPA)) for f in ("ukf", "srukf", "ekf")}
    fx, hx = (lambda x, dt_: F @ x), (lambda x: pm.ranges(x, b))
    if "filterpy" in peers:
        makers["FilterPy UKF"] = lambda: pm.filterpy_ukf(fx, hx, x0, P0, Q, Rp, dt, ALPHA, BETA, KAPPA)
        if n == 4:
            makers["FilterPy EKF"] = lambda: pm.filterpy_ekf(F, Q, hx, lambda x: pm.ranges_jacobian(x, b), x0, P0, Rp)
    if "stonesoup" in peers and n == 4:
        fxc = lambda X, dt_: F @ X  # noqa: E731 - Stone Soup's sigma points as columns, vectorised
        hxc = lambda X: np.sqrt(((X[None, :b.shape[1], :] - b[:, :, None]) ** 2).sum(axis=1))  # noqa: E731
        makers["Stone Soup UKF"] = lambda: pm.stonesoup_ukf(fx, hx, x0, P0, Q, Rp, dt, ALPHA, BETA, KAPPA, fxc, hxc)
    row = f"{n}-state CV + 4 ranges"
    refs = {kind: run_steps(makers[f"fusion {kind}"], p["zs"]) for kind in ("ukf", "ekf")}
    for name, make in makers.items():
        if name not in ("fusion ukf", "fusion ekf"):
            ref = refs["ekf" if name.endswith("EKF") else "ukf"]
            check(row, name, agreement(ref, run_steps(make, p["zs"])), EXACT_TOL, agree)
    return interleave({k: stepper(m, p["zs"]) for k, m in makers.items()}, args.rounds)


def ins_rows(peers: list[str], args, agree: list, r_scale: float) -> dict[str, tuple[float, float]]:
    """us per IMU predict + position-fix update on the 16-state INS (fusion's ``ins`` and ``position``)."""
    from bench_filters import ins_position_model

    process, model, x0, P0, u, z0, R, dt = ins_position_model()
    pr = process.params
    noise = (pr.accel_noise_density, pr.gyro_noise_density, pr.accel_bias_rw, pr.gyro_bias_rw, pr.quat_norm_variance)
    lever = np.array([0.2, 0.0, -0.1])
    rng = np.random.default_rng(2)
    zs = [z0 + rng.normal(0, 0.05, 3) for _ in range(max(5, args.steps // 4))]
    Rp = R * r_scale
    fx = lambda x, dt_: pm.ins_f(x, u, dt_)  # noqa: E731
    hx = lambda x: pm.position_h(x, lever)  # noqa: E731
    makers = {f"fusion {f}": (lambda f=f: pm.fusion_single(f, process, model, x0, P0, u, R, dt, ALPHA, BETA, KAPPA))
              for f in ("ukf", "srukf")}
    if "filterpy" in peers:
        makers["FilterPy UKF"] = lambda: _filterpy_ins(fx, hx, x0, P0, noise, Rp, dt)
    if "stonesoup" in peers:
        makers["Stone Soup UKF"] = lambda: pm.stonesoup_ukf(fx, hx, x0, P0, pm.ins_Q(x0, dt, *noise), Rp, dt,
                                                            ALPHA, BETA, KAPPA, normalize=_unit_q)
    row = "16-state INS + position fix"
    ref = run_steps(makers["fusion ukf"], zs)
    for name, make in makers.items():
        if name != "fusion ukf":
            tol = EXACT_TOL if name != "Stone Soup UKF" else INS_CONST_Q_TOL
            check(row, name, agreement(ref, run_steps(make, zs)), tol, agree)
    return interleave({k: stepper(m, zs) for k, m in makers.items()}, args.rounds)


def _unit_q(x: np.ndarray) -> None:
    x[6:10] /= np.linalg.norm(x[6:10])


INS_CONST_Q_TOL = 1e-6   # Stone Soup's transition covar() gets no state: Q(x0) throughout, not Q(x_k)


def _filterpy_ins(fx, hx, x0, P0, noise, R, dt):
    """FilterPy's UKF on the plain INS, with Q(x, dt) at its prior mean before each predict and the mean's
    quaternion renormalised after predict and update (the sigma points redrawn from it), as the project's
    filters do."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    ukf = UnscentedKalmanFilter(16, 3, dt, hx, fx, MerweScaledSigmaPoints(16, ALPHA, BETA, KAPPA))
    ukf.x, ukf.P, ukf.R = x0.copy(), P0.copy(), R

    def step(z):
        ukf.Q = pm.ins_Q(ukf.x, dt, *noise)
        ukf.predict()
        ukf.x[6:10] /= np.linalg.norm(ukf.x[6:10])            # unit quaternion mean, as the project's filters
        ukf.sigmas_f = ukf.points_fn.sigma_points(ukf.x, ukf.P)
        ukf.update(z)
        ukf.x[6:10] /= np.linalg.norm(ukf.x[6:10])
    return step, lambda: (ukf.x.copy(), ukf.P.copy())


def batch_rows(peers: list[str], args, agree: list, r_scale: float) -> dict[str, tuple[float, float]]:
    """Filter-steps per second of N filters over T steps (seconds per filter-step, CPU and wall)."""
    N, T = args.batch_n, args.batch_steps
    x0, Z = pbt.problem(N, T)
    L = max(2, N // 50)
    runners, refs = {}, {}
    for f in ("ukf", "ekf"):
        refs[f] = pbt.fusion_batch(f, x0, Z, ALPHA, BETA, KAPPA)
        runners[f"fusion batched {f}"] = (lambda r=refs[f]: r, lambda r: r(), N * T)
    for f in ("ukf", "ekf"):
        ref = refs[f]()
        if "dynamax" in peers:
            dyn = pbt.dynamax_batch(f, x0, Z, ALPHA, BETA, KAPPA)
            check(f"{N} batched 4-state filters", f"dynamax {f.upper()} (vmap)", agreement(ref, dyn()), DYNAMAX_TOL, agree)
            runners[f"dynamax {f} (jit of vmap)"] = (lambda r=dyn: r, lambda r: r(), N * T)
        if "filterpy" in peers:
            loop = pbt.filterpy_loop(f, x0[:L], Z[:L], ALPHA, BETA, KAPPA, r_scale)
            check(f"{N} batched 4-state filters", f"FilterPy {f.upper()} (loop)",
                  agreement((ref[0][:L], ref[1][:L]), loop()), EXACT_TOL, agree)
            runners[f"FilterPy {f} (loop of {L})"] = (lambda r=loop: r, lambda r: r(), L * T)
    return interleave(runners, max(3, args.rounds // 4))


def whole_process(repeats: int) -> dict[str, float]:
    """Median child CPU and wall time of ``fusion run configs/abps_ins.yaml -q`` and the recording's span."""
    import subprocess

    root = HERE.parent
    cmd = [sys.executable, "-m", "fusion.cli", "run", CONFIG, "-q"]
    env = {**os.environ}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=root, env=env, check=True)
    cpu, wall = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=root, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        if status != 0:
            raise SystemExit(f"{' '.join(cmd)} failed (status {status})")
        wall.append(time.perf_counter() - t0)
        cpu.append(usage.ru_utime + usage.ru_stime)
    from fusion.config import load_system
    rec = load_system(root / CONFIG).recording
    with open(rec) as fh:
        span = next(float(line.split(":", 1)[1]) for line in fh if line.startswith("# duration:"))
    return {"cpu_s": statistics.median(cpu), "wall_s": statistics.median(wall), "span_s": span}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a smoke test: few rounds and steps, n = 4 and 8")
    ap.add_argument("--peers", default=",".join(PEERS), help="comma-separated subset of " + ",".join(PEERS))
    ap.add_argument("--rounds", type=int, default=21, help="interleaved rounds (median kept; default 21)")
    ap.add_argument("--steps", type=int, default=100, help="predict + update steps a round (default 100)")
    ap.add_argument("--batch-n", type=int, default=1000)
    ap.add_argument("--batch-steps", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=5, help="whole-process runs (median; default 5)")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "peers.md")
    ap.add_argument("--r-scale", type=float, default=1.0, help=argparse.SUPPRESS)   # the test's wrong noise
    args = ap.parse_args(argv)
    if args.quick:
        args.rounds, args.steps, args.batch_n, args.batch_steps, args.repeats = 3, 20, 100, 10, 1
    peers, skipped = available([p.strip() for p in args.peers.split(",") if p.strip()])
    env = environment(peers, skipped)
    agree: list = []
    res: dict = {"load_before": os.getloadavg()}
    try:
        res["cv"] = {n: cv_rows(n, peers, args, agree, args.r_scale) for n in ((4, 8) if args.quick else (4, 8, 16, 32))}
        res["ins"] = ins_rows(peers, args, agree, args.r_scale)
        res["batch"] = batch_rows(peers, args, agree, args.r_scale)
    except AgreementError as exc:
        print(f"bench_peers: {exc}", file=sys.stderr)
        return 1
    res["process"] = whole_process(args.repeats)
    res["load_after"] = os.getloadavg()
    res["batch_nt"] = (args.batch_n, args.batch_steps)
    cmd = " ".join(["python", "benchmarks/bench_peers.py", *(sys.argv[1:] if argv is None else argv)])
    text = write_page(args.out, cmd, env, res, agree, args)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
