"""PNG figures of docs/results/uwb.md (like paper 001 figs. 2-5, plus the statistics over seeds)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from uwb_cases import MANOEUVRE_ACCEL, Case, config_of, phase_masks, run_pair, scenario_of, trajectory_of
from uwb_report import verdict
from uwb_cases import paired

COL = {"ukf": "tab:blue", "ekf": "tab:red", "truth": "black"}
SHIPPED_SEED = {("route1", "optimal"): 10, ("route1", "line"): 11, ("route2", "optimal"): 20, ("route2", "line"): 21}
CORNER = (24.0, 29.5, 0.5, 7.0)      # x0, x1, y0, y1 (m): the lower right corner of route 1 (27, 3)
VISIBLE = {"scenario": {"sensors": {"uwb": {"rate_hz": 0.5}}}, "config": {"process": {"spectral_density": 1.0}}}


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, fig_dir: Path, name: str) -> str:
    """Lay out, write fig_dir/name at 110 dpi, close; returns the file name for the page."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(fig_dir / name, dpi=110)
    plt.close(fig)
    return name


def _beacons(ax, case: Case) -> None:
    B = np.array(list(config_of(case)["beacons"].values()), float)
    ax.plot(B[:, 0], B[:, 1], "^", color="tab:green", ms=9, label="beacons", zorder=5)


def _track(ax, run: dict, filters=("ukf", "ekf"), lw=1.0) -> None:
    first = run[filters[0]]
    ax.plot(first["p"][:, 0], first["p"][:, 1], "--", color=COL["truth"], lw=1.2, label="truth")
    for f in filters:
        ax.plot(run[f]["x"][:, 0], run[f]["x"][:, 1], "-", color=COL[f], lw=lw, label=f.upper(), alpha=0.85)


def tracks(fig_dir: Path) -> str:
    """Paper figs. 2-3: UKF tracks on both routes, both layouts (the shipped recordings)."""
    plt = _plt()
    fig, axs = plt.subplots(2, 2, figsize=(12, 8.5))
    for ax, (route, lay) in zip(axs.ravel(), SHIPPED_SEED):
        case = Case("fig", route, lay)
        run = run_pair(case, SHIPPED_SEED[route, lay], keep_tracks=True)
        _track(ax, run, ("ukf",))
        _beacons(ax, case)
        u = run["ukf"]
        ax.set_title(f"{route.replace('route', 'route ')}, {'beacons around' if lay == 'optimal' else 'beacons on one line'}: "
                     f"UKF RMSE {u['rmse_all']:.3f} m, max {u['max_all']:.2f} m", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.grid(alpha=0.3)
    axs[0, 0].legend(loc="center", fontsize=8)
    fig.suptitle("Paper 001 figs. 2-3 reproduced: UKF track against truth (shipped recordings, "
                 "fusion run configs/uwb_pv_ukf*.yaml)", fontsize=11)
    return _save(fig, fig_dir, "tracks.png")


def corner(fig_dir: Path, layout: str) -> str:
    """Paper figs. 4-5: UKF and EKF on route 1 with a zoom on the lower right corner, as configured and in
    the regime where the difference is visible (0.5 cycles/s, S = 1)."""
    plt = _plt()
    fig, axs = plt.subplots(2, 2, figsize=(12, 9), gridspec_kw={"width_ratios": [1.5, 1]})
    seed = SHIPPED_SEED["route1", layout]
    for row, (title, over) in enumerate((("as configured: 5 cycles/s (20 ranges/s), S = 0.2", {}),
                                         ("few ranges: 0.5 cycles/s (2 ranges/s), S = 1", VISIBLE))):
        case = Case("fig", "route1", layout, **over)
        run = run_pair(case, seed, keep_tracks=True)
        for col, ax in enumerate(axs[row]):
            _track(ax, run)
            _beacons(ax, case)
            if col == 1:
                ax.plot(run["ukf"]["x"][:, 0], run["ukf"]["x"][:, 1], ".", color=COL["ukf"], ms=3)
                ax.plot(run["ekf"]["x"][:, 0], run["ekf"]["x"][:, 1], ".", color=COL["ekf"], ms=3)
                ax.set_xlim(CORNER[0], CORNER[1])
                ax.set_ylim(CORNER[2], CORNER[3])
                ax.set_title(f"zoom on the corner; RMSE during / after manoeuvres\nUKF {run['ukf']['rmse_man']:.3f} / "
                             f"{run['ukf']['rmse_after']:.3f} m, EKF {run['ekf']['rmse_man']:.3f} / "
                             f"{run['ekf']['rmse_after']:.3f} m", fontsize=9)
            else:
                ax.set_title(f"{title}\nRMSE UKF {run['ukf']['rmse_all']:.3f} m, EKF {run['ekf']['rmse_all']:.3f} m",
                             fontsize=10)
                ax.add_patch(plt.Rectangle((CORNER[0], CORNER[2]), CORNER[1] - CORNER[0], CORNER[3] - CORNER[2],
                                           fill=False, ls=":", color="gray"))
            ax.set_aspect("equal")
            ax.grid(alpha=0.3)
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
    axs[0, 0].legend(loc="center", fontsize=8)
    lay = "beacons around the area" if layout == "optimal" else "four beacons on one line"
    fig.suptitle(f"Paper 001 fig. {4 if layout == 'optimal' else 5} reproduced: route 1, {lay}, seed {seed}",
                 fontsize=11)
    fig.tight_layout()
    path = fig_dir / f"corner_{layout}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def errors_over_time(fig_dir: Path, rows_by_case: dict) -> str:
    """Median error over seeds against time, and the paired UKF - EKF difference, for the four cases."""
    plt = _plt()
    names = list(rows_by_case)
    fig, axs = plt.subplots(2, len(names), figsize=(4.2 * len(names), 6.5), sharex="col",
                            gridspec_kw={"height_ratios": [2, 1]})
    for j, name in enumerate(names):
        rows = rows_by_case[name]
        t = rows[0]["ukf"]["t"]
        n = min(len(r["ukf"]["e"]) for r in rows)
        eu = np.array([r["ukf"]["e"][:n] for r in rows])
        ee = np.array([r["ekf"]["e"][:n] for r in rows])
        t = t[:n]
        route, lay = name.split("_")
        traj = trajectory_of(scenario_of(Case("t", route, lay)))
        man = phase_masks(t, traj)["man"]
        for ax in axs[:, j]:
            ax.fill_between(t, 0, 1, where=man, transform=ax.get_xaxis_transform(), color="orange", alpha=0.3,
                            lw=0, label=f"|a| > {MANOEUVRE_ACCEL:g} m/s^2")
        for f, E in (("ukf", eu), ("ekf", ee)):
            axs[0, j].plot(t, np.median(E, axis=0), color=COL[f], lw=0.9, label=f"{f.upper()} median")
        axs[0, j].set_ylim(0, max(0.35, float(np.percentile(np.median(ee, axis=0), 99.5)) * 1.2))
        axs[0, j].set_title(name.replace("_", ", ").replace("line", "collinear"), fontsize=10)
        d = 1000.0 * (eu - ee)
        axs[1, j].plot(t, np.median(d, axis=0), color="purple", lw=0.8, label="median UKF - EKF")
        axs[1, j].fill_between(t, *np.percentile(d, [25, 75], axis=0), color="purple", alpha=0.25, lw=0,
                               label="quartiles")
        axs[1, j].axhline(0, color="k", lw=0.5)
        axs[1, j].set_xlabel("t (s)")
        lim = max(1.0, float(np.percentile(np.abs(np.median(d, axis=0)), 99)) * 2)
        axs[1, j].set_ylim(-lim, lim)
    axs[0, 0].set_ylabel("position error (m)")
    axs[1, 0].set_ylabel("UKF - EKF (mm)")
    axs[0, 0].legend(fontsize=7)
    axs[1, 0].legend(fontsize=7)
    fig.suptitle(f"Position error over time, {len(rows_by_case[names[0]])} seeds a case (as shipped)", fontsize=11)
    return _save(fig, fig_dir, "errors_over_time.png")


SHORT = {"rmse_all": "RMSE", "rmse_man": "RMSE during manoeuvres", "rmse_after": "RMSE after manoeuvres",
         "rmse_init": "RMSE first 5 s", "rmse_steady": "RMSE steady", "rmse_near": "RMSE near beacons"}


def regimes(fig_dir: Path, results: dict, picks: list[tuple[str, str, str]], labels: dict) -> str:
    """Forest plot: median [quartiles] of UKF/EKF - 1 for each (study, case, metric) of ``picks``."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 0.32 * len(picks) + 1.5))
    ticks = []
    picks = [pk for pk in picks if paired(results[pk[0]][pk[1]], pk[2]).get("n")]
    for i, (key, name, metric) in enumerate(picks):
        st = paired(results[key][name], metric)
        v = verdict(st)
        c = {"UKF lower": "tab:blue", "UKF higher": "tab:red"}.get(v, "gray")
        y = len(picks) - i
        med, q1, q3 = (100 * st[k] for k in ("rel_median", "rel_q1", "rel_q3"))
        ax.plot([q1, q3], [y, y], color=c, lw=3, alpha=0.5)
        ax.plot(med, y, "o", color=c)
        ticks.append((y, f"{labels.get((key, name), name)}: {SHORT.get(metric, metric)}"))
    ax.axvline(0, color="k", lw=0.7)
    ax.set_yticks([y for y, _ in ticks], [s for _, s in ticks], fontsize=7)
    ax.set_xscale("symlog", linthresh=1.0)
    xt = [-50, -10, -1, 0, 1, 10, 50]
    ax.set_xticks(xt, [f"{v:+d}" if v else "0" for v in xt])
    ax.set_xlabel("UKF / EKF - 1 (%), median and quartiles over seeds; blue: UKF lower, red: higher (p < 0.01)")
    ax.grid(alpha=0.3, axis="x")
    return _save(fig, fig_dir, "regimes.png")


def collinear(fig_dir: Path, results: dict) -> str:
    """A walk 0.5 m from the beacons' line: a seed where a filter ends on the mirror side; offset in sd."""
    plt = _plt()
    rows = results["collinear"]["line_graze"]
    pick = next((r["seed"] for r in rows if r["ekf"]["mirror_end"] or r["ukf"]["mirror_end"]), rows[0]["seed"])
    case = Case("line_graze", layout="line", initial="drawn",
                scenario={"trajectory": {"waypoints": [[3.0, 3.0], [8.0, 0.5], [22.0, 0.5], [27.0, 3.0]]}})
    run = run_pair(case, pick, keep_tracks=True)
    fig, axs = plt.subplots(3, 1, figsize=(11, 10), gridspec_kw={"height_ratios": [1.3, 1, 1]})
    _track(axs[0], run)
    _beacons(axs[0], case)
    axs[0].plot(run["ukf"]["p"][:, 0], -run["ukf"]["p"][:, 1], ":", color="gray", label="mirror of truth")
    axs[0].axhline(0, color="tab:green", lw=0.6)
    axs[0].set_aspect("equal")
    axs[0].legend(fontsize=8, ncol=5)
    axs[0].set_title(f"walk 0.5 m from the line of beacons, seed {pick}", fontsize=10)
    for f in ("ukf", "ekf"):
        t = run[f]["t"]
        axs[1].plot(t, run[f]["x"][:, 1], color=COL[f], lw=0.9, label=f"{f.upper()} y")
        axs[2].semilogy(t, np.maximum(run[f]["offset_sigma"], 1e-3), color=COL[f], lw=0.9,
                        label=f"{f.upper()}: distance to the line / sd")
    axs[1].plot(run["ukf"]["t"], run["ukf"]["p"][:, 1], "--", color="k", label="truth y")
    axs[1].axhline(0, color="tab:green", lw=0.6)
    axs[1].set_ylabel("y (m)")
    axs[1].legend(fontsize=8)
    axs[2].axhline(3.0, color="k", ls=":", label="warning threshold (mirror_warn_sigma = 3)")
    axs[2].set_ylabel("offset (sd)")
    axs[2].set_xlabel("t (s)")
    axs[2].legend(fontsize=8)
    for ax in axs:
        ax.grid(alpha=0.3)
    return _save(fig, fig_dir, "collinear.png")


def make_figures(fig_dir: Path, results: dict, labels: dict | None = None) -> dict[str, str]:
    picks = [("cases", n, "rmse_all") for n in results["cases"]]
    picks += [("cases", n, m) for n in results["cases"] for m in ("rmse_man", "rmse_after")]
    picks += [("initial", n, "rmse_init") for n in results["initial"]]
    picks += [("rate", n, m) for n in results["rate"] for m in ("rmse_steady", "rmse_man")]
    picks += [("close", n, "rmse_near") for n in results["close"]]
    picks += [("matched", n, "rmse_all") for n in results["matched"]]
    return {"tracks": tracks(fig_dir), "corner_optimal": corner(fig_dir, "optimal"),
            "corner_line": corner(fig_dir, "line"), "errors": errors_over_time(fig_dir, results["cases"]),
            "regimes": regimes(fig_dir, results, picks, labels or {}), "collinear": collinear(fig_dir, results)}
