"""fusion sweep end to end: rows, resume, failures recorded, summary statistics, Parquet, the smoother,
and bad input (one line, exit 2)."""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from fusion.cli import main
from fusion.sweep.grid import split_values, sweep
from fusion.sweep.results import read_rows
from fusion.sweep.stats import mean_ci, paired

from .conftest import CONFIG, ROOT, SCENARIO


def test_rows_and_resume(trials, tmp_path):
    out = tmp_path / "r.csv"
    rows, info = sweep(trials(seeds=range(2)), out, engine="serial")
    assert len(rows) == 4 and info["skipped"] == 0 and info["engines"] == {"pipeline": 4}
    assert all(r["status"] == "ok" and r["position_rmse_m"] > 0 for r in rows)
    rows2, info2 = sweep(trials(seeds=range(3)), out, engine="serial")       # one more seed: 2 new trials
    assert info2["skipped"] == 4 and info2["engines"] == {"pipeline": 2} and len(rows2) == 6
    on_disk = read_rows(out)
    assert len(on_disk) == 6 and sorted({r["seed"] for r in on_disk}) == [0, 1, 2]
    by_key = {r["key"]: r for r in rows}
    for r in on_disk[:4]:
        assert r["position_rmse_m"] == pytest.approx(by_key[r["key"]]["position_rmse_m"], rel=1e-15)


def test_a_failing_trial_is_a_row_and_the_sweep_goes_on(trials, tmp_path, monkeypatch):
    from fusion.sweep import trial as trial_mod

    real = trial_mod.recording_of

    def boom(t):
        if t.seed == 1:
            raise RuntimeError("simulator exploded")
        return real(t)

    monkeypatch.setattr(trial_mod, "recording_of", boom)
    out = tmp_path / "r.csv"
    rows, _ = sweep(trials(seeds=range(3), filters=("ukf",)), out, engine="serial")
    status = {r["seed"]: r["status"] for r in rows}
    assert status == {0: "ok", 1: "error", 2: "ok"}
    bad = next(r for r in rows if r["seed"] == 1)
    assert bad["error"] == "RuntimeError: simulator exploded"
    monkeypatch.setattr(trial_mod, "recording_of", real)                   # a rerun retries only the failure
    rows, info = sweep(trials(seeds=range(3), filters=("ukf",)), out, engine="serial")
    assert info["skipped"] == 2 and {r["status"] for r in rows} == {"ok"} and len(rows) == 3


def test_params_vary_the_run(trials, tmp_path):
    """--param values reach the config: a larger range noise in the filter gives a smaller NIS."""
    ts = trials(seeds=range(2), filters=("ukf",), params=[("sensors.uwb.noise.sd", ["0.1", "0.4"])])
    rows, _ = sweep(ts, tmp_path / "p.csv", engine="auto")
    nis = {r["param.sensors.uwb.noise.sd"]: [] for r in rows}
    for r in rows:
        nis[r["param.sensors.uwb.noise.sd"]].append(r["nis_mean_uwb"])
    assert max(nis["0.4"]) < min(nis["0.1"]) / 4


def test_parquet_equals_csv(trials, tmp_path):
    import pyarrow  # noqa: F401  (a test dependency; for users parquet is optional, the CSV path needs nothing)
    ts = trials(seeds=range(2), filters=("ukf",))
    a, _ = sweep(ts, tmp_path / "r.csv", engine="serial")
    b, _ = sweep(ts, tmp_path / "r.parquet", engine="serial")
    pa = {r["key"]: r for r in read_rows(tmp_path / "r.parquet")}
    assert len(pa) == 2
    for r in a:
        assert pa[r["key"]]["position_rmse_m"] == pytest.approx(r["position_rmse_m"], rel=1e-15)


def test_smoothed_columns(trials, tmp_path):
    rows, _ = sweep(trials(seeds=range(2), filters=("ukf",), smooth=True), tmp_path / "s.csv", engine="auto")
    for r in rows:
        assert r["engine"] == "pipeline"
        assert 0 < r["smoothed_position_rmse_m"] < r["position_rmse_m"]
        assert math.isfinite(r["smoothed_nees_mean"])


def test_statistics_against_scipy():
    from scipy import stats

    rng = np.random.default_rng(1)
    v = rng.normal(3.0, 1.0, 25)
    m, lo, hi, n = mean_ci(v.tolist())
    ref = stats.t.interval(0.95, 24, loc=v.mean(), scale=stats.sem(v))
    assert (n, m) == (25, pytest.approx(v.mean())) and (lo, hi) == pytest.approx(ref)
    a, b = v, v + rng.normal(0.3, 0.2, 25)
    res = paired(a, b)
    assert res["p"] == pytest.approx(stats.wilcoxon(a, b).pvalue) and res["a_lower"] > 0.8
    assert paired([1.0, 2.0], [1.0, 2.0])["p"] == 1.0


def test_split_values():
    assert split_values("0.1,0.2") == ["0.1", "0.2"]
    assert split_values("[1, 2],[3, 4],'a,b'") == ["[1, 2]", "[3, 4]", "'a,b'"]


def test_cli_end_to_end(tmp_path, capsys):
    out = tmp_path / "c.csv"
    rc = main(["sweep", CONFIG, "--scenario", SCENARIO, "--seeds", "2", "--filter", "ukf,ekf",
               "--param", "scenario.duration=8", "-o", str(out), "--no-progress"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "mean [95% CI] over seeds" in text and "Wilcoxon" in text
    with open(out) as fh:
        assert len(list(csv.DictReader(fh))) == 4


@pytest.mark.parametrize("extra,needle", [
    (["--param", "process.spectral_density"], "--param 'process.spectral_density': expected KEY=V1,V2"),
    (["--param", "process.spectral_density=-1"], "spectral_density"),
    # a sensor simulator's parameter is checked before any trial too (not an error row in each)
    (["--param", "scenario.sensors.uwb.rate_hz=0"], "(with --param): sensors.uwb.rate_hz: Input should be greater"),
    (["--filter", "nosuch"], "nosuch"),
    (["--seeds", "x"], "--seeds 'x'"),
    (["-o", "r.txt"], "must end in .csv or .parquet"),
    (["--scenario", "nosuch.yaml"], "nosuch.yaml"),
    (["-o", "nodir/r.csv"], "no such directory 'nodir'"),
    (["-o", CONFIG], "must end in .csv or .parquet"),
    (["--seeds", "100000000000"], "at most 1000000"),
    (["-o", "bad.parquet"], "not a readable Parquet results file"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, extra, needle, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.parquet").write_bytes(b"junk")
    args = ["sweep", CONFIG, "--scenario", SCENARIO, "--seeds", "2", "-o", "r.csv", "--no-progress"]
    for i in range(0, len(extra), 2):      # later options replace earlier ones
        if extra[i] in args:
            j = args.index(extra[i])
            args[j + 1] = extra[i + 1]
        else:
            args += extra[i:i + 2]
    rc = main(args)
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "r.csv").exists() or extra[0] != "-o"


def test_an_output_that_is_an_input_is_refused(tmp_path, capsys):
    """-o naming the config itself (here through a link, with a .csv name) would overwrite it: exit 2."""
    import shutil

    cfg = tmp_path / "cfg.csv"
    shutil.copy(CONFIG, cfg)
    link = tmp_path / "link.csv"
    link.symlink_to(cfg)
    before = cfg.read_bytes()
    assert main(["sweep", str(cfg), "--scenario", SCENARIO, "--seeds", "1", "-o", str(link), "--no-progress"]) == 2
    assert "is the input" in capsys.readouterr().err and cfg.read_bytes() == before


def test_a_row_cut_by_an_interrupted_sweep_is_run_again(trials, tmp_path):
    """The last row cut in half (the sweep was killed while writing): reading skips it, the resumed sweep
    runs that trial again and appends after it."""
    ts = trials(seeds=range(3), filters=("ukf",))
    out = tmp_path / "r.csv"
    sweep(ts, out, engine="serial")
    text = out.read_text()
    out.write_text(text[:-40])                        # the last row loses its end (and its newline)
    assert len(read_rows(out)) == 2
    rows, info = sweep(ts, out, engine="serial")
    assert info["skipped"] == 2 and len(rows) == 3
    assert {r["key"] for r in read_rows(out)} == {t.key() for t in ts}


@pytest.mark.parametrize("keep", [0.2, 0.8])
def test_a_header_cut_by_an_interrupted_start_is_written_again(trials, tmp_path, keep):
    """Killed while writing the header (no row yet): the file holds part of this sweep's header; the rerun
    starts it afresh instead of calling it another sweep's file. A header that differs is still refused."""
    from fusion.api import ConfigError

    ts = trials(seeds=range(2), filters=("ukf",))
    out = tmp_path / "r.csv"
    sweep(ts, out, engine="serial")
    header = out.read_text().splitlines()[0]
    out.write_text(header[:int(len(header) * keep)])
    rows, info = sweep(ts, out, engine="serial")
    assert info["skipped"] == 0 and len(rows) == 2
    assert out.read_text().splitlines()[0] == header and len(read_rows(out)) == 2
    out.write_text(header[:10] + "X" + header[11:int(len(header) * keep)])
    with pytest.raises(ConfigError, match="its columns are not this sweep's"):
        sweep(ts, out, engine="serial")


def test_missing_dask_is_a_clear_message(monkeypatch):
    import builtins

    from fusion.api import ConfigError
    from fusion.sweep.engines import dask_client

    real = builtins.__import__

    def no_dask(name, *a, **k):
        if name.startswith("dask"):
            raise ImportError(name)
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_dask)
    with pytest.raises(ConfigError, match=r"pip install 'fusion-estimator\[cluster\]'"):
        dask_client("local", 2)


def test_default_scenario_is_the_one_that_made_the_recording(tmp_path):
    from fusion.api import ConfigError
    from fusion.sweep.grid import default_scenario

    assert default_scenario(CONFIG).endswith("scenarios/uwb_route1.yaml")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(open(CONFIG).read().replace("recording: ../recordings/uwb_route1.log", "recording: null"))
    with pytest.raises(ConfigError, match="give --scenario"):
        default_scenario(str(cfg))


def test_a_bad_param_value_names_the_param_without_an_empty_field_path(capsys):
    assert main(["sweep", CONFIG, "--scenario", SCENARIO, "--seeds", "1", "--param",
                 "process.spectral_density=-1,0.2", "-o", "unused.csv", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "(with --param process.spectral_density=-1): process: " in err and ": :" not in err
    assert "spectral_density must be >= 0" in err


def test_a_scenario_without_the_configs_sensors_gives_failed_rows_that_say_why(tmp_path):
    """No estimate at all (the scenario has none of the config's sensors): not an 'ok' row full of blanks."""
    from fusion.sweep.grid import trials_of

    ts = trials_of(CONFIG, str(ROOT / "scenarios" / "car_gps_mag.yaml"), range(1), ["ukf"],
                   [("scenario.duration", ["5.0"])], False, "config")
    rows, _ = sweep(ts, tmp_path / "r.csv", engine="serial")
    assert [r["status"] for r in rows] == ["error"]
    assert "never initialised" in rows[0]["error"]
