"""Gauss-Markov blocks of the ``ins`` process (plugins/process/ins_gauss_markov.py) and the ``position`` model's
offset block: exact discretisation, the INS part unchanged, vectorised over sigma points, the batched-inputs
path, the Jacobians, every filter and the smoother, and the wiring errors."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from fusion.api import BuildContext, StateLayout
from fusion.cli import main
from fusion.testing.models import check_process
from fusion_plugins.measurement.position import Position, PositionParams
from fusion_plugins.process.ins import Ins, InsParams
from fusion_plugins.process.ins_gauss_markov import InsGaussMarkov

ROOT = Path(__file__).resolve().parents[2]
G = 9.80665
GM = [{"name": "hz", "size": 1, "tau": 10.0, "sd": 0.1}, {"name": "o", "size": 2, "tau": 3.0, "sd": 0.5}]


def make(**kw):
    return Ins(InsParams(gauss_markov=GM, integration="trapezoidal", **kw))


def states(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.zeros((n, 19))
    x[:, 0:6] = rng.normal(0, 1, (n, 6))
    q = rng.normal(0, 1, (n, 4))
    x[:, 6:10] = q / np.linalg.norm(q, axis=1, keepdims=True)
    x[:, 10:16] = rng.normal(0, 0.01, (n, 6))
    x[:, 16:19] = rng.normal(0, 0.3, (n, 3))
    return x


def test_the_default_is_the_16_state_ins_and_the_blocks_are_appended():
    assert type(Ins(InsParams())) is Ins and Ins(InsParams()).layout.n == 16
    m = make()
    assert isinstance(m, InsGaussMarkov)
    assert m.layout.n == 19 and m.layout["hz"] == slice(16, 17) and m.layout["o"] == slice(17, 19)
    assert m.layout.names[16:] == ("hz", "ox", "oy")
    assert m.layout.blocks[:5] == Ins(InsParams()).layout.blocks
    with pytest.raises(ValueError, match="unique"):
        InsParams(gauss_markov=[{"name": "p", "tau": 1.0, "sd": 1.0}])
    with pytest.raises(ValueError):
        InsParams(gauss_markov=[{"name": "hz", "tau": 0.0, "sd": 1.0}])


def test_propagation_is_the_ins_plus_the_exact_decay_vectorised():
    m, core = make(), Ins(InsParams(integration="trapezoidal"))
    X, u, dt = states(9), np.r_[0.1, -0.2, -G, 0.3, -0.1, 0.2], 0.01
    Y = m.f(X, u, dt)                                        # all sigma points in one call
    np.testing.assert_allclose(Y[:, :16], core.f(X[:, :16], u, dt), rtol=0, atol=1e-15)
    decay = np.exp(-dt / np.array([10.0, 3.0, 3.0]))
    np.testing.assert_allclose(Y[:, 16:], X[:, 16:] * decay, rtol=1e-15)
    np.testing.assert_allclose(np.stack([m.f(x, u, dt) for x in X]), Y, rtol=0, atol=1e-15)
    check_process(Ins, {"gauss_markov": GM}, u=u, states=X)   # vectorised, Q PSD, Jacobian vs numerical


def test_noise_is_the_exact_discretisation_of_the_stationary_process():
    """Independent properties of the Ornstein-Uhlenbeck transition: stationary (F sd^2 F + Q = sd^2) and a
    semigroup (Q over dt1 + dt2 = F2 Q1 F2 + Q2), the INS block unchanged, no cross terms."""
    m, core = make(), Ins(InsParams(integration="trapezoidal"))
    x, u = states(1)[0], np.r_[0, 0, -G, 0, 0, 0]
    sd2 = np.array([0.01, 0.25, 0.25])
    for dt in (0.01, 0.4, 25.0):
        Q, F = m.Q(x, u, dt), m.jacobian(x, u, dt)
        np.testing.assert_allclose(Q[:16, :16], core.Q(x[:16], u, dt), rtol=0, atol=0)
        assert not Q[:16, 16:].any() and not F[:16, 16:].any() and not F[16:, :16].any()
        f, q = np.diag(F)[16:], np.diag(Q)[16:]
        np.testing.assert_allclose(f * sd2 * f + q, sd2, rtol=1e-13)
    f1, q1 = np.diag(m.jacobian(x, u, 0.3))[16:], np.diag(m.Q(x, u, 0.3))[16:]
    f2, q2 = np.diag(m.jacobian(x, u, 0.7))[16:], np.diag(m.Q(x, u, 0.7))[16:]
    np.testing.assert_allclose(np.diag(m.Q(x, u, 1.0))[16:], f2 * q1 * f2 + q2, rtol=1e-13)
    np.testing.assert_allclose(np.diag(m.jacobian(x, u, 1.0))[16:], f1 * f2, rtol=1e-15)


def test_batched_noise_equals_state_by_state():
    m = make()
    X, u = states(4, seed=5), np.r_[0, 0, -G, 0, 0, 0]
    np.testing.assert_allclose(m.Q_batch(X, u, 0.01), np.stack([m.Q(x, u, 0.01) for x in X]), rtol=0, atol=1e-18)


def test_simulated_statistics_over_many_seeds():
    """Sampling x_k+1 = F x_k + N(0, Q) from the stationary start, over 4000 seeds: the variance stays sd^2 and
    the lag-T correlation is exp(-T / tau) (the continuous process's), within sampling error."""
    m = Ins(InsParams(gauss_markov=[{"name": "hz", "tau": 2.0, "sd": 0.1}]))
    rng = np.random.default_rng(7)
    x0 = np.zeros(17)
    x0[6] = 1.0
    F, Q = m.jacobian(x0, np.r_[0, 0, -G, 0, 0, 0], 0.1), m.Q(x0, np.r_[0, 0, -G, 0, 0, 0], 0.1)
    b0 = rng.normal(0, 0.1, 4000)
    b = b0.copy()
    for _ in range(20):                                      # 2 s = one tau
        b = F[16, 16] * b + rng.normal(0, np.sqrt(Q[16, 16]), b.size)
    assert abs(b.std() / 0.1 - 1.0) < 4 * np.sqrt(0.5 / b.size)
    assert abs(np.corrcoef(b0, b)[0, 1] - np.exp(-1.0)) < 4 / np.sqrt(b.size)


def test_batched_inputs_path_equals_sample_by_sample():
    m = make()
    rng = np.random.default_rng(3)
    X = states(5, seed=1)
    us = np.c_[rng.normal(0, 0.3, (12, 2)), -G + rng.normal(0, 0.3, 12), rng.normal(0, 0.2, (12, 3))]
    dts = np.full(12, 0.01)
    Y = X
    for uu, dt in zip(us, dts):
        Y = m.f(Y, uu, dt)
    np.testing.assert_allclose(m.f_inputs(X, us, dts), Y, rtol=0, atol=1e-12)
    core = Ins(InsParams(integration="trapezoidal"))
    x1 = m.f_inputs(X[0], us, dts)
    Qi = m.Q_inputs(X[0], x1, us, dts)
    np.testing.assert_allclose(Qi[:16, :16], core.Q_inputs(X[0, :16], x1[:16], us, dts), rtol=0, atol=0)
    np.testing.assert_allclose(np.diag(Qi)[16:], np.diag(m.Q(X[0], us[0], 0.12))[16:], rtol=1e-14)


def test_alignment_and_step_events_come_from_the_ins():
    m = make(eta=50.0)
    x0 = np.zeros(19)
    x0[6], x0[16] = 1.0, 0.05
    x, P = m.align(x0, np.eye(19), np.r_[0.0, 0.0, -G, 1e-3, -2e-3, 3e-4])
    np.testing.assert_allclose(x[13:16], [1e-3, -2e-3, 3e-4])
    assert x[16] == 0.05 and np.array_equal(P, np.eye(19))
    assert [e.kind for e in m.step_events(1.0, np.array([0.01, 0.05]))] == ["eta_clamped"]


# --------------------------------------------------------------------------- position with an offset block
def position(layout: StateLayout, **kw) -> Position:
    return Position(PositionParams(lever_arm=(0.2, 0.0, -0.4), **kw), BuildContext(layout=layout))


def test_position_adds_the_offset_block_to_the_named_axes():
    m = make()
    plain, off = position(m.layout), position(m.layout, offset_block="hz", offset_axes=(2,))
    X = states(7, seed=2)
    Z = off.h(X)                                            # vectorised over the points
    np.testing.assert_allclose(Z - plain.h(X), np.c_[np.zeros((7, 2)), X[:, 16]], rtol=0, atol=1e-15)
    two = position(m.layout, offset_block="o", offset_axes=(1, 0))
    np.testing.assert_allclose(two.h(X) - plain.h(X), np.c_[X[:, 18], X[:, 17], np.zeros(7)], atol=1e-15)
    for model in (off, two):
        x = X[0]
        H = model.jacobian(x)
        eps = 1e-6
        Hn = np.stack([(model.h(x + eps * e) - model.h(x - eps * e)) / (2 * eps) for e in np.eye(19)], axis=1)
        np.testing.assert_allclose(H, Hn, atol=1e-8)
        z = model.h(x)
        x2 = x.copy()
        x2[0:3] = model.position_from(z, x)                  # the inverse, with the offset taken out
        np.testing.assert_allclose(x2[0:3], x[0:3], atol=1e-12)


@pytest.mark.parametrize("kw, needle", [
    ({"offset_block": "hz"}, "no block of the state"),
    ({"offset_block": "ba", "offset_axes": (0, 3, 1)}, "offset_axes"),
    ({"offset_block": "p"}, "already measures"),
    ({"offset_axes": (2,)}, "needs offset_block"),
])
def test_position_offset_errors(kw, needle):
    from fusion.api import ConfigError

    layout = Ins(InsParams()).layout
    with pytest.raises(ConfigError, match=needle):
        position(layout, **kw)


def test_validate_names_the_line_of_a_missing_offset_block(tmp_path, capsys):
    """A config whose position model names a block the process does not make: exit 2, file:line."""
    text = (ROOT / "configs" / "abps_ins.yaml").read_text()
    text = re.sub(r"  gauss_markov:\n    - \{[^}]*\}\n", "", text)
    text = text.replace(", hz: 0.0}", "}").replace(", hz: 0.1}", "}").replace("../recordings", str(ROOT / "recordings"))
    cfg = tmp_path / "abps_no_hz.yaml"
    cfg.write_text(text)
    assert main(["validate", str(cfg)]) == 2
    err = capsys.readouterr().err
    line = next(i for i, ln in enumerate(text.splitlines(), 1) if "offset_block: hz" in ln)
    assert "offset_block 'hz' is no block of the state" in err
    assert re.search(rf"abps_no_hz\.yaml:{line}\b", err), err


# --------------------------------------------------------------------------- filters and smoother
def _short(tmp_path: Path, seconds: float = 40.0) -> Path:
    lines = (ROOT / "recordings" / "abps_mine.log").read_text().splitlines()
    keep = [ln for ln in lines if ln.startswith("#") or float(ln.split(",", 1)[0]) <= seconds]
    log = tmp_path / "short.log"
    log.write_text("\n".join(keep) + "\n")
    return log


def test_every_filter_and_the_smoother_run_the_shipped_config_with_the_block(tmp_path):
    """configs/abps_ins.yaml (hz block): srukf and ukf agree (as without the block), the EKF is close, and the
    smoother of each gives a belief over all 17 states whose hz sd is below its prior's."""
    from fusion import pipeline
    from fusion.config import load_system
    from fusion.smoothing import run_smoothed

    log = _short(tmp_path)
    out = {}
    for flt in ("srukf", "ukf", "ekf"):
        system = load_system(ROOT / "configs" / "abps_ins.yaml", filter_override=flt)
        assert system.layout.n == 17 and "hz" in system.layout
        fwd, sm = pipeline.Collect(), pipeline.Collect()
        run_smoothed(system, str(log), [sm], forward_sinks=[fwd])
        xf = np.array([e.belief.x for e in fwd.estimates])
        xs = np.array([e.belief.x for e in sm.estimates])
        ss = np.array([e.belief.sd for e in sm.estimates])
        assert xs.shape == xf.shape and xs.shape[1] == 17 and np.isfinite(xs).all()
        assert ss[:, 16].max() < 0.1                         # the fixes told the smoother something about hz
        out[flt] = xf
    np.testing.assert_allclose(out["ukf"], out["srukf"], atol=1e-6)
    assert np.abs(out["ekf"][:, :3] - out["srukf"][:, :3]).max() < 0.05


@pytest.mark.parametrize("blocks, needle", [
    ([{"name": "px", "tau": 1.0, "sd": 1.0}], "'px' appears twice"),            # an INS element's name
    ([{"name": "qw", "tau": 1.0, "sd": 1.0}], "'qw' appears twice"),
    ([{"name": "t", "tau": 1.0, "sd": 1.0}], "taken by the outputs"),          # the time column
    ([{"name": "sd_x", "tau": 1.0, "sd": 1.0}], "taken by the outputs"),
    ([{"name": "hz", "tau": 1.0, "sd": 1.0}, {"name": "h", "size": 3, "tau": 1.0, "sd": 1.0}], "'hz' appears twice"),
])
def test_block_names_never_shadow_another_column(blocks, needle):
    """An element name repeated or taken by the outputs would overwrite a column (the time, px) in the CSV
    and JSONL estimates: refused when the state is built."""
    with pytest.raises(ValueError, match=needle):
        Ins(InsParams(gauss_markov=blocks))


@pytest.mark.parametrize("bad", [{"tau": 0.0}, {"tau": 1e12}, {"sd": 0.0}, {"sd": 1e160}, {"sd": float("nan")}])
def test_block_parameters_are_bounded(bad):
    from pydantic import ValidationError

    with pytest.raises(ValidationError):
        InsParams(gauss_markov=[{"name": "hz", "tau": 10.0, "sd": 0.1, **bad}])
