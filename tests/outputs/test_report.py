"""fusion.report: every section of the summary renders; the progress bar appears only when asked and late."""
import io

from rich.console import Console

from fusion.report import print_summary, progress

SUMMARY = {
    "config": "configs/uwb_pv_ukf.yaml", "filter": "ukf", "input": "recordings/uwb_route1.log",
    "duration_s": 120.0, "wall_s": 0.8, "steps": {"predict": 12000, "update": 4800},
    "us_per_predict": 35.2, "us_per_update": 61.7,
    "sensors": {"uwb": {"received": 4800, "used": 4790, "rejected": 10, "malformed": 1, "late": 0}},
    "errors": {"position_rmse_m": 0.1234, "position_max_m": 0.5, "velocity_rmse_mps": 0.05,
               "attitude_rmse_deg": 1.5, "attitude_max_deg": 4.25, "element_rmse": {"bax": 0.002}, "samples": 4800},
    "consistency": {"nees_mean": 4.1, "nees_in_95_fraction": 0.94, "nees_dof": 4, "nees_samples": 4800,
                    "nis_mean": {"uwb": 1.02}, "nis_in_95_fraction": {"uwb": 0.951}, "nis_dof": {"uwb": 1}},
    "events": {"rejected": 10},
}


def render(summary):
    buf = io.StringIO()
    print_summary(summary, console=Console(file=buf, width=120, color_system=None))
    return buf.getvalue()


def test_all_sections_render():
    out = render(SUMMARY)
    for text in ("configs/uwb_pv_ukf.yaml", "ukf", "recordings/uwb_route1.log", "120 s", "0.8 s",
                 "150.0 x real time", "12,000 predict", "4,800 update", "35.2 us", "61.7 us",
                 "Sensors", "received", "used", "rejected", "malformed", "late", "4,790",
                 "Errors against truth", "position RMSE", "0.1234", "position max", "velocity RMSE",
                 "attitude RMSE", "attitude max", "4.25", "bax RMSE",
                 "Consistency", "NEES", "4.1", "94.0 %", "NIS uwb", "1.02", "95.1 %", "events", "rejected: 10"):
        assert text in out, text


def test_minimal_summary_without_truth():
    out = render({"config": "c.yaml", "filter": "ekf", "duration_s": 1.0, "wall_s": 0.0, "steps": {},
                  "us_per_predict": None, "consistency": {"nis_mean": {}}})
    assert "c.yaml" in out and "no truth" in out and "NEES" not in out


def test_progress_hidden_by_default_delay_and_shown_when_forced():
    buf = io.StringIO()
    con = Console(file=buf, force_terminal=True, width=100)
    with progress(10.0, enabled=True, console=con) as tick:    # 2 s delay: a fast replay shows nothing
        for k in range(100):
            tick(0.1 * k)
    assert not tick.shown and buf.getvalue() == ""
    with progress(10.0, enabled=True, console=con, delay_s=0.0) as tick:
        for k in range(101):
            tick.update(0.1 * k)
    assert tick.shown and "replay" in buf.getvalue()
    buf2 = io.StringIO()
    with progress(None, enabled=False, console=Console(file=buf2), delay_s=0.0) as tick:
        tick(1.0)
    assert not tick.shown and buf2.getvalue() == "" and tick.t == 1.0


def test_nis_rows_are_the_accepted_updates_per_dof_and_the_rejected_apart():
    """Not 'NIS us | 4 | 15.4' for 1-dof arrivals whose accepted mean is 0.76."""
    c = {"nis_mean": {"us": 15.4}, "nis_in_95_fraction": {"us": 0.926}, "nis_dof": {"us": 4},
         "nis_samples": {"us": 1322}, "nis_accepted_mean": {"us": 0.761}, "nis_accepted_samples": {"us": 1238},
         "nis_accepted_in_95_fraction": {"us": 0.968}, "nis_accepted_dofs": {"us": [1, 4]},
         "nis_accepted_mean_per_dof": {"us": 0.758}, "nis_accepted_mean_per_dof_95": {"us": [0.923, 1.08]},
         "nis_accepted_by_dof": {"us": {"1": {"mean": 0.7612, "in_95_fraction": 0.968, "samples": 1237},
                                        "4": {"mean": 0.00114, "in_95_fraction": 0.0, "samples": 1}}},
         "nis_rejected_mean": {"us": 230.5}, "nis_rejected_samples": {"us": 84}}
    out = render({**SUMMARY, "consistency": c})
    assert "15.4" not in out
    for text in ("NIS us, dof 1", "0.761", "1,237", "NIS us, dof 4", "NIS us, all / dof (0.923-1.08)", "0.758",
                 "1,238", "NIS us, rejected by the gate", "230", "84"):
        assert text in out, text
    one = {**c, "nis_accepted_by_dof": {}, "nis_accepted_dofs": {"us": [1]}}
    out = render({**SUMMARY, "consistency": one})
    assert "NIS us " in out and "0.761" in out and "dof 1" not in out


def test_a_long_rejection_run_is_said_even_without_a_reset():
    """14 fixes in a row refused and 'resets: 0': the run of rejections is said."""
    health = {"resets": 0, "locked_out": {"abps": {"rejected": 14, "from_s": 13.14, "for_s": 6.38}}}
    out = render({**SUMMARY, "health": health})
    assert "abps: 14 updates in a row rejected over 6.38 s from t 13.14 s" in out
    assert "0 recovery resets" in out
