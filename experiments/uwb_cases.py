"""Paper 001 (UWB personal navigation): one simulated run of both filters, and its errors by phase.

Shared by experiments/uwb_ukf_vs_ekf.py (the full study behind docs/results/uwb.md) and
tests/systems/test_uwb.py (a reduced multi-seed comparison). A ``Case`` is a shipped scenario and config
(scenarios/uwb_*.yaml, configs/uwb_pv_ukf*.yaml) plus overrides, deep-merged into both YAML documents:
changing the beacons, the process noise, the initial belief or the route needs no new files.

``run_pair(case, seed)`` simulates the case's recording with ``seed`` (``fusion.simulate``, written to a
temporary file) and replays it through the system twice, once with ``ukf`` and once with ``ekf``
(``fusion.config.wire`` with ``filter_override`` and ``fusion.pipeline.run``): the two
filters see the same ranges, so their errors pair by seed.

Errors are evaluated at every estimate (one per range, 20 a second) against the exact trajectory of the
simulator (position error norm, m), split by phase using the true acceleration:

* ``man``: during a manoeuvre, |a| > ``MANOEUVRE_ACCEL`` (1 m/s^2: the sharp corners, side-steps and the
  reversal of routes 1 and 2, 3-5 m/s^2; not the ordinary 2 m corners, 0.7 m/s^2, nor starting and
  stopping, 0.8 m/s^2);
* ``after``: the ``AFTER_S`` (3 s) that follow the end of a manoeuvre;
* ``init``: the first ``INIT_S`` (5 s), the convergence from the initial belief;
* ``settled``: everything after ``INIT_S``;
* ``steady``: the rest (after ``INIT_S``, neither during nor after a manoeuvre);
* ``near``: the true position within ``NEAR_M`` (3 m) of a beacon (close passes; after ``INIT_S``);
* ``all``: every estimate (what ``fusion run`` reports as position RMSE / max).
"""
from __future__ import annotations

import copy
import math
import os
import tempfile
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
MANOEUVRE_ACCEL = 1.0   # m/s^2
AFTER_S = 3.0           # s
INIT_S = 5.0            # s
NEAR_M = 3.0            # m
FILTERS = ("ukf", "ekf")
PHASES = ("all", "init", "settled", "steady", "man", "after", "near")

CONFIG = {"optimal": "configs/uwb_pv_ukf.yaml", "line": "configs/uwb_pv_ukf_line.yaml"}
SCENARIO = {("route1", "optimal"): "scenarios/uwb_route1.yaml", ("route1", "line"): "scenarios/uwb_route1_line.yaml",
            ("route2", "optimal"): "scenarios/uwb_route2.yaml", ("route2", "line"): "scenarios/uwb_route2_line.yaml"}


@dataclass(frozen=True)
class Case:
    """A scenario and a config (by route and layout) with overrides.

    ``scenario``/``config``: nested dicts deep-merged into the YAML documents (a list replaces a list);
    ``beacons``: a beacon layout set in both; ``initial``: ``"config"`` (the config's initial mean, the
    same every seed) or ``"drawn"`` (mean drawn per seed from N(true start, P0) of the config: a Monte-Carlo
    over initial errors); ``focus``: a time window (s) reported separately as phase ``focus``;
    ``matched``: instead of the scenario's walk, a truth drawn from the filter's own PV model (see
    ``matched_recording``), with these keyword arguments; ``vector``: the paper's update, one 4-range
    vector per cycle (eq. 6) instead of one range a message (see ``vector_log``)."""

    name: str
    route: str = "route1"
    layout: str = "optimal"
    scenario: dict[str, Any] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    beacons: dict[str, list[float]] | None = None
    initial: str = "config"
    focus: tuple[float, float] | None = None
    matched: dict[str, Any] | None = None
    vector: bool = False
    label: str = ""


def deep_merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


@lru_cache(maxsize=None)
def _yaml(rel: str) -> dict:
    return yaml.safe_load((ROOT / rel).read_text())


def scenario_of(case: Case):
    """The validated fusion.simulate Scenario of a case."""
    from fusion.simulate.scenario import Scenario

    data = deep_merge(_yaml(SCENARIO[case.route, case.layout]), case.scenario)
    if case.beacons is not None:
        data["beacons"] = copy.deepcopy(case.beacons)
    data["name"] = f"{data.get('name', 'uwb')}_{case.name}"
    return Scenario.model_validate(data)


def config_of(case: Case) -> dict[str, Any]:
    """The system YAML document of a case (a dict), with its overrides."""
    data = deep_merge(_yaml(CONFIG[case.layout]), case.config)
    if case.beacons is not None:
        data["beacons"] = copy.deepcopy(case.beacons)
    data["recording"] = None
    return data


def trajectory_of(sc):
    from fusion.simulate.trajectory import build_trajectory

    return build_trajectory(sc.trajectory, sc.dim, sc.duration)


def system_of(case: Case, filter_name: str, seed: int, traj=None):
    """The wired System of a case for one filter (and, for ``initial: drawn``, this seed's initial mean)."""
    from fusion.config import SystemSpec, wire

    data = config_of(case)
    if case.initial == "drawn":
        if traj is None:
            traj = trajectory_of(scenario_of(case))
        k0 = traj.sample(np.array([0.0]))
        sd = data["initial"]["sd"]
        rng = np.random.default_rng([seed, 1979660])   # independent of the ranges' noise, same for both filters
        p = k0.p[0, :2] + rng.normal(0.0, 1.0, 2) * float(np.mean(sd["p"]))
        v = k0.v[0, :2] + rng.normal(0.0, 1.0, 2) * float(np.mean(sd["v"]))
        data["initial"]["mean"] = {"p": p.tolist(), "v": v.tolist()}
    spec = SystemSpec.model_validate(data)
    fspec = data["filter"] if isinstance(data["filter"], dict) else {"type": data["filter"]}
    if filter_name != fspec["type"]:   # the config's parameters belong to its own filter (the UKF's alpha...)
        fspec = {"type": filter_name}
    return wire(spec, path=ROOT / CONFIG[case.layout], filter_override=fspec)


def phase_masks(t: np.ndarray, traj, focus: tuple[float, float] | None = None,
                beacons: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Boolean masks over estimate times ``t`` for each phase (see the module docstring)."""
    k = traj.sample(t)
    acc = np.linalg.norm(k.a[:, :2], axis=1)
    man = acc > MANOEUVRE_ACCEL
    # end times of the manoeuvres, from a fine grid so that short ones are not missed between estimates
    tg = np.arange(0.0, float(t.max()) + 0.01, 0.01) if t.size else np.zeros(0)
    mg = np.linalg.norm(traj.sample(tg).a[:, :2], axis=1) > MANOEUVRE_ACCEL if tg.size else np.zeros(0, bool)
    ends = tg[1:][mg[:-1] & ~mg[1:]]
    after = np.zeros_like(man)
    for te in ends:
        after |= (t >= te) & (t < te + AFTER_S)
    after &= ~man
    init = t < t.min() + INIT_S if t.size else np.zeros(0, bool)
    masks = {"all": np.ones_like(man), "init": init, "settled": ~init, "steady": ~(init | man | after), "man": man,
             "after": after}
    if beacons is not None and len(beacons):
        dist = np.linalg.norm(k.p[:, None, :2] - np.asarray(beacons, float)[None, :, :2], axis=2).min(axis=1)
        masks["near"] = (dist < NEAR_M) & ~init
    if focus is not None:
        masks["focus"] = (t >= focus[0]) & (t <= focus[1])
    return masks


def errors_of(t: np.ndarray, x: np.ndarray, P: np.ndarray, traj, focus=None, mirror_axis: str | None = None,
              beacons: np.ndarray | None = None) -> dict[str, Any]:
    """RMSE / max per phase, NEES, and (collinear layouts) time spent on the mirror side."""
    k = traj.sample(t)
    d = x[:, :2] - k.p[:, :2]
    e = np.hypot(d[:, 0], d[:, 1])
    out: dict[str, Any] = {}
    for name, m in phase_masks(t, traj, focus, beacons).items():
        out[f"rmse_{name}"] = float(np.sqrt(np.mean(e[m] ** 2))) if m.any() else math.nan
        out[f"max_{name}"] = float(e[m].max()) if m.any() else math.nan
    err = np.concatenate([d, x[:, 2:4] - k.v[:, :2]], axis=1)
    nees = np.einsum("ki,ki->k", err, np.linalg.solve(P, err[..., None])[..., 0])
    out["nees_mean"] = float(np.mean(nees))
    if mirror_axis == "y":
        # beacons on the line y = 0: an estimate is "at the line" when it has fallen halfway or more towards
        # it (|y_est| < |y_true| / 2, either side), "on the mirror side" when it is across it and farther
        far = np.abs(k.p[:, 1]) > 0.5          # the true position is clearly off the line
        stuck = far & (np.abs(x[:, 1]) < 0.5 * np.abs(k.p[:, 1]))
        wrong = far & (x[:, 1] * k.p[:, 1] < 0) & ~stuck
        out["mirror_fraction"] = float(wrong.sum() / max(far.sum(), 1))
        out["line_fraction"] = float(stuck.sum() / max(far.sum(), 1))
        last = np.flatnonzero(far)[-1] if far.any() else None
        out["mirror_end"] = bool(wrong[last]) if last is not None else False
        out["line_end"] = bool(stuck[last]) if last is not None else False
        bad = np.flatnonzero(wrong | stuck)
        out["bad_t"] = float(t[bad[0]]) if bad.size else math.inf
    return out


class SampledTruth:
    """A truth trajectory known at sample times (``t``, ``p``, ``v`` (N, 2)), linearly interpolated; no
    acceleration (a white-noise-acceleration truth has no manoeuvres to single out)."""

    def __init__(self, t: np.ndarray, p: np.ndarray, v: np.ndarray):
        self.t, self.p, self.v = t, p, v

    def sample(self, t: np.ndarray):
        from types import SimpleNamespace

        t = np.asarray(t, float)
        p = np.column_stack([np.interp(t, self.t, self.p[:, i]) for i in range(2)] + [np.zeros_like(t)])
        v = np.column_stack([np.interp(t, self.t, self.v[:, i]) for i in range(2)] + [np.zeros_like(t)])
        return SimpleNamespace(p=p, v=v, a=np.zeros_like(p))


def matched_recording(seed: int, beacons: dict[str, list[float]], duration: float = 20.0,
                      spectral_density: float = 1.0, rate_hz: float = 5.0, noise_sd: float = 0.1,
                      start: tuple[float, float] = (15.0, 10.0), speed: float = 1.2,
                      dt: float = 0.01) -> tuple[str, SampledTruth]:
    """A recording whose truth is drawn from the filter's own model: the PV model of paper 001 eq. 3
    with the Q of eq. 4 (``spectral_density`` S per axis, m^2/s^3), exactly discretised over ``dt``;
    ranges (eq. 6, Gaussian noise ``noise_sd``) to the beacons in turn, ``rate_hz`` cycles a second. The
    start is ``start`` moving at ``speed`` in a random direction. With the filter's S equal to this S, its
    covariance is an honest description of its error (a consistent prior), which the walking routes of
    fusion.simulate (straight legs and sharp corners) do not give."""
    from fusion.logformat import format_line

    rng = np.random.default_rng([seed, 1, 1979660])
    n = int(round(duration / dt))
    Q1 = spectral_density * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    L = np.linalg.cholesky(Q1)
    w = rng.standard_normal((n, 2, 2)) @ L.T                  # (step, axis, [dp dv])
    head = rng.uniform(0, 2 * np.pi)
    p = np.zeros((n + 1, 2))
    v = np.zeros((n + 1, 2))
    p[0] = start
    v[0] = speed * np.array([np.cos(head), np.sin(head)])
    for k in range(n):
        p[k + 1] = p[k] + dt * v[k] + w[k, :, 0]
        v[k + 1] = v[k] + w[k, :, 1]
    t = np.arange(n + 1) * dt
    truth = SampledTruth(t, p, v)
    names = list(beacons)
    B = np.array([beacons[b] for b in names], float)
    spacing = 1.0 / (rate_hz * len(names))
    ts = np.arange(0.0, duration, spacing)
    idx = np.arange(ts.size) % len(names)
    k = truth.sample(ts)
    r = np.abs(np.linalg.norm(k.p[:, :2] - B[idx], axis=1) + rng.normal(0.0, noise_sd, ts.size))
    lines = ["# fusion-log 1", f"# scenario: matched_pv seed {seed}", "# fields uwb beacon range",
             "# fields truth px py vx vy"]
    for ti, i, ri, pi, vi in zip(ts, idx, r, k.p, k.v):
        lines.append(format_line(ti, "uwb", [names[i], float(ri)], precision=6))
        lines.append(format_line(ti, "truth", [pi[0], pi[1], vi[0], vi[1]], precision=6))
    return "\n".join(lines) + "\n", truth


def vector_log(text: str) -> str:
    """The paper's measurement vector (eq. 6): the ranges of one cycle merged into one message
    ``t,uwb,B1,r1,B2,r2,...`` at the time of the cycle's last range. The scenario must range a whole cycle
    within a few ms (``spacing_s``) so that merging moves no range by more than millimetres."""
    out, cycle, seen = [], [], set()

    def flush():
        if cycle:
            out.append(f"{cycle[-1][0]},uwb," + ",".join(f"{b},{r}" for _, b, r in cycle))
            cycle.clear()
            seen.clear()

    for line in text.splitlines():
        if line.startswith("# fields uwb"):
            continue
        if ",uwb," in line:
            t, _, b, r = line.split(",")
            if b in seen:
                flush()
            cycle.append((t, b, r))
            seen.add(b)
            continue
        if not line.startswith("#") and cycle and float(line.split(",", 1)[0]) > float(cycle[-1][0]) + 0.01:
            flush()
        out.append(line)
    flush()
    return "\n".join(out) + "\n"


def run_pair(case: Case, seed: int, keep_tracks: bool = False, tmpdir: str | None = None,
             keep_errors: bool = False) -> dict[str, Any]:
    """Simulate ``case`` with ``seed`` and run ukf and ekf over the same recording.

    Returns ``{"case", "seed", "ukf": metrics, "ekf": metrics}``; metrics hold the phase errors (``rmse_all``
    and ``max_all`` are what ``fusion run`` reports as position RMSE / max: tests/systems/test_uwb.py checks
    it), NEES, rejected ranges, the wall time and the range model's geometry check at every estimate (``warnings``: how many warnings ``check`` gave, ``gdop_max``,
    ``offset_sigma_min``); with ``keep_errors`` also ``t`` and the error norm ``e`` at each estimate;
    with ``keep_tracks`` also ``t``, ``x``, ``sd`` (estimates), the truth ``p`` and
    the per-estimate ``gdop`` and ``offset_sigma``."""
    from fusion import pipeline
    from fusion.simulate import simulate

    if case.matched is not None:
        text, traj = matched_recording(seed, case.beacons or config_of(case)["beacons"], **case.matched)
    else:
        sc = scenario_of(case)
        traj = trajectory_of(sc)
        text = simulate(sc, seed=seed)
    if case.vector:
        text = vector_log(text)
    fd, path = tempfile.mkstemp(prefix=f"uwb_{case.name}_{seed}_", suffix=".log", dir=tmpdir)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        out: dict[str, Any] = {"case": case.name, "seed": seed}
        mirror = "y" if case.layout == "line" and case.beacons is None else None
        for flt in FILTERS:
            system = system_of(case, flt, seed, traj)
            kept = pipeline.Collect()
            res = pipeline.run(system, path, [kept])
            est = kept.estimates
            t = np.array([e.t for e in est])
            x = np.array([e.belief.x for e in est])
            P = np.array([e.belief.cov for e in est])
            m = errors_of(t, x, P, traj, case.focus, mirror, np.array(list(system.beacons.values())))
            model = system.sensors["uwb"].model                  # the range model's geometry check, batched
            geo = model.geometry(x, P)
            gw, mw = model.warnings(geo)
            m["warnings"] = int(gw.sum() + mw.sum())
            m["warned"] = bool(gw.any() or mw.any())
            m["warn_t"] = float(t[np.flatnonzero(gw | mw)[0]]) if m["warned"] else math.inf
            m["gdop_max"] = float(geo["gdop"].max())
            m["offset_sigma_min"] = float(geo["offset_sigma"].min()) if "offset_sigma" in geo else math.inf
            m["rejected"] = res.summary["sensors"]["uwb"]["rejected"]
            m["wall_s"] = res.wall_s
            if keep_errors:
                m["t"] = t
                m["e"] = np.hypot(*(x[:, :2] - traj.sample(t).p[:, :2]).T).astype(np.float32)
            if keep_tracks:
                m["t"], m["x"], m["p"] = t, x, traj.sample(t).p[:, :2]
                m["sd"] = np.sqrt(P[:, [0, 1], [0, 1]])
                m["gdop"] = geo["gdop"]
                m["offset_sigma"] = geo.get("offset_sigma", np.full(t.shape, np.inf))
            out[flt] = m
        return out
    finally:
        os.unlink(path)


# --------------------------------------------------------------------------- statistics over seeds
def paired(rows: list[dict[str, Any]], metric: str) -> dict[str, Any]:
    """Paired comparison of ``metric`` (ukf vs ekf) over seeds: means, sds, the median and quartiles of the
    relative difference ukf/ekf - 1, the fraction of seeds where the UKF is lower, and the two-sided
    Wilcoxon signed-rank p-value (scipy.stats.wilcoxon; 1.0 when every difference is zero)."""
    from scipy.stats import wilcoxon

    u = np.array([r["ukf"][metric] for r in rows], float)
    e = np.array([r["ekf"][metric] for r in rows], float)
    ok = np.isfinite(u) & np.isfinite(e)
    u, e = u[ok], e[ok]
    rel = u / e - 1.0
    diff = u - e
    if u.size == 0:
        return {"n": 0}
    try:
        p = float(wilcoxon(u, e).pvalue) if np.any(diff != 0) else 1.0
    except ValueError:
        p = 1.0
    q1, med, q3 = np.percentile(rel, [25, 50, 75])
    return {"n": int(u.size), "ukf_mean": float(u.mean()), "ukf_sd": float(u.std(ddof=1)) if u.size > 1 else 0.0,
            "ekf_mean": float(e.mean()), "ekf_sd": float(e.std(ddof=1)) if e.size > 1 else 0.0,
            "rel_median": float(med), "rel_q1": float(q1), "rel_q3": float(q3),
            "ukf_better": float(np.mean(diff < 0)), "p": p}
