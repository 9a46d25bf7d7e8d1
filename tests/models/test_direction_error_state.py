"""The directions' discretisation error as state (paper 003 pose filter, issue 17): the receiver colouring,
``direction`` with ``error_state: true`` and the ``firing_clock`` blocks ``dir_err_<beacon>`` (their
Gauss-Markov noise, its coupling to the attitude noise, the slot reset), checked against numerical
differences, batch evaluation, the models' contract (immutable: the same numbers twice) and their refusals."""
from __future__ import annotations

import numpy as np
import pytest

from fusion import quaternion as quat
from fusion.api import BuildContext, ConfigError, Message
from fusion_plugins.measurement.direction import (Direction, adjacent_receivers, receiver_colours,
                                                  receiver_normals, tangent_basis)
from fusion_plugins.process.firing_clock import FiringClock

BEACONS = {"B1": np.array([0.0, 0.0, 0.0]), "B2": np.array([2.6, 0.0, 0.0]),
           "B3": np.array([0.0, 2.6, 0.0]), "B4": np.array([0.0, 0.0, 2.6])}
NORMALS = receiver_normals("truncated_icosahedron")


def process(**kw) -> FiringClock:
    params = dict(attitude_sd_deg=0.57, direction_error_sd_deg=10.2, direction_error_tau_s=133.0)
    params.update(kw)
    return FiringClock(FiringClock.Params(**params), BuildContext(beacons=BEACONS))


def direction(proc: FiringClock, **kw) -> Direction:
    params = dict(arrival=True, error_state=True, sd_deg=2.0)
    params.update(kw)
    return Direction(Direction.Params(**{"receivers": "truncated_icosahedron", **params}), BuildContext(proc.layout, BEACONS, "us"))


def state(proc: FiringClock, rng, e_sd: float = 0.1) -> np.ndarray:
    lay = proc.layout
    x = np.zeros(lay.n)
    x[lay["p"]] = rng.uniform(0.7, 2.3, 3)
    x[lay["T"]] = 0.225
    x[lay["t"]] = 10.0
    x[lay["q"]] = quat.normalize(rng.normal(size=4))
    for b in BEACONS:
        x[lay[f"dir_err_{b}"]] = rng.normal(0.0, e_sd, lay[f"dir_err_{b}"].stop - lay[f"dir_err_{b}"].start)
    return x


def numeric_jacobian(fun, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((fun(x + d) - fun(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)


def test_the_truncated_icosahedron_has_four_colours_and_adjacent_cells_differ():
    adj = adjacent_receivers(NORMALS)
    assert sorted(set(adj.sum(axis=1).tolist())) == [5, 6]          # pentagons 5 neighbours, hexagons 6
    ang = np.degrees(np.arccos(np.clip(NORMALS @ NORMALS.T, -1, 1)))[adj]
    assert ang.min() > 37.0 and ang.max() < 42.0                     # 37.4 / 41.8 deg, paper 003 sec. 3
    c = receiver_colours(NORMALS)
    assert c.max() + 1 == 4
    i, j = np.nonzero(adj)
    assert np.all(c[i] != c[j])


def test_tangent_basis_is_orthonormal_and_normal_to_the_receiver():
    T = tangent_basis(NORMALS)
    assert T.shape == (32, 2, 3)
    np.testing.assert_allclose(np.einsum("kad,kbd->kab", T, T), np.broadcast_to(np.eye(2), (32, 2, 2)), atol=1e-12)
    np.testing.assert_allclose(np.einsum("kad,kd->ka", T, NORMALS), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.cross(T[:, 0], T[:, 1]), NORMALS, atol=1e-12)


def test_the_process_has_one_block_of_slots_per_beacon():
    proc = process()
    for b in BEACONS:
        sl = proc.layout[f"dir_err_{b}"]
        assert sl.stop - sl.start == 12                              # 4 colours x 3 body axes
    assert proc.layout.n == 9 + 4 * 12
    assert proc.layout.names[9] == "dir_err_B1_0"


@pytest.mark.parametrize("receiver", [1, 13, 27])
def test_direction_h_is_vectorised_and_its_jacobian_is_the_numerical_one(receiver):
    rng = np.random.default_rng(receiver)
    proc = process()
    model = direction(proc, position_from_direction=True).observe(Message(5.0, "us", ("B2", "5.0", str(receiver)))).model
    assert model.dim == 3                                            # arrival + 2 tangent components
    alone = direction(proc).observe(Message(5.0, "us", ("B2", "5.0", str(receiver)))).model
    xs = np.stack([state(proc, rng) for _ in range(5)])
    batch = model.h(xs)
    assert batch.shape == (5, 3)
    for x, hb in zip(xs, batch):
        np.testing.assert_allclose(model.h(x), hb, rtol=0, atol=1e-15)
        np.testing.assert_allclose(model.jacobian(x), numeric_jacobian(model.h, x), atol=1e-7)
        H = alone.jacobian(x)                       # position_from_direction false: no dh/dp for the direction
        np.testing.assert_array_equal(H[1:, :3], 0.0)
        np.testing.assert_array_equal(H[:, 3:], model.jacobian(x)[:, 3:])


def test_direction_h_is_zero_when_the_error_slot_holds_the_discretisation():
    """z = 0 = T_r (u + e): with e = n_r - u in the slot of the receiver's colour, h's direction part is 0."""
    rng = np.random.default_rng(3)
    proc = process()
    x = state(proc, rng, e_sd=0.0)
    C = quat.to_matrix(x[proc.layout["q"]])
    w = BEACONS["B3"] - x[proc.layout["p"]]
    u = C.T @ w / np.linalg.norm(w)
    r = int(np.argmax(NORMALS @ u)) + 1
    c = receiver_colours(NORMALS)[r - 1]
    blk = proc.layout["dir_err_B3"]
    x[blk.start + 3 * c: blk.start + 3 * c + 3] = NORMALS[r - 1] - u
    obs = direction(proc).observe(Message(5.0, "us", ("B3", "5.0", str(r))))
    np.testing.assert_array_equal(obs.z[1:], 0.0)
    np.testing.assert_allclose(obs.model.h(x)[1:], 0.0, atol=1e-15)


def test_direction_with_the_cell_constraint_keeps_its_jacobian():
    rng = np.random.default_rng(5)
    proc = process()
    model = direction(proc, cell=True, position_from_direction=True).observe(Message(5.0, "us", ("B1", "5.0", "7"))).model
    assert model.dim == 4
    for _ in range(5):
        x = state(proc, rng)
        H = model.jacobian(x)
        np.testing.assert_allclose(H[:3], numeric_jacobian(model.h, x)[:3], atol=1e-7)


@pytest.mark.parametrize("coupling", ["direction", "direction_position", "none"])
def test_process_f_is_vectorised_and_its_jacobian_is_the_numerical_one(coupling):
    rng = np.random.default_rng(7)
    proc = process(direction_error_coupling=coupling)
    xs = np.stack([state(proc, rng, e_sd=0.02) for _ in range(4)])       # small errors: no slot resets
    assert not proc._resets(xs).any()
    fb = proc.f(xs, None, 0.225)
    for x, f in zip(xs, fb):
        np.testing.assert_allclose(proc.f(x, None, 0.225), f, rtol=0, atol=1e-15)
        F = proc.jacobian(x, None, 0.225)
        N = numeric_jacobian(lambda y: proc.f(y, None, 0.225), x)
        np.testing.assert_allclose(F, N, atol=1e-7)
        a = np.exp(-0.225 / 133.0)
        np.testing.assert_allclose(f[9:], a * x[9:], rtol=1e-14)
        Q = proc.Q(x, None, 0.225)
        np.testing.assert_allclose(Q, Q.T, atol=1e-18)
        assert np.linalg.eigvalsh(Q).min() > -1e-15
        np.testing.assert_array_equal(proc.Q(x, None, 0.225), Q)       # immutable: the same numbers twice


def test_coupled_noise_leaves_the_measured_direction_in_place():
    """direction coupling: the error moves by minus the direction's own motion, so the predicted measured
    direction T_r (u + e) gets no variance from the attitude noise (tau long: no independent rest); with
    ``none`` it gets the attitude's."""
    rng = np.random.default_rng(11)
    x = state(process(), rng, e_sd=0.02)
    dt = 0.225
    out = {}
    for coupling in ("direction", "none"):
        proc = process(direction_error_coupling=coupling, direction_error_tau_s=1e6)
        model = direction(proc).observe(Message(5.0, "us", ("B4", "5.0", "20"))).model
        H = model.jacobian(x)[1:]
        out[coupling] = H @ proc.Q(x, None, dt) @ H.T
    att = np.deg2rad(0.57) ** 2
    assert np.abs(out["direction"]).max() < 1e-3 * att
    assert np.trace(out["none"]) > 0.5 * att


def test_a_slot_resets_when_the_direction_enters_a_new_cell_of_its_colour():
    proc = process()
    lay = proc.layout
    x = state(proc, np.random.default_rng(2), e_sd=0.0)
    C = quat.to_matrix(x[lay["q"]])
    w = BEACONS["B1"] - x[lay["p"]]
    u = C.T @ w / np.linalg.norm(w)
    here = int(np.argmax(NORMALS @ u))
    colour = receiver_colours(NORMALS)
    c = colour[here]
    other = next(r for r in np.argsort(-(NORMALS @ u)) if colour[r] == c and r != here)
    blk = lay["dir_err_B1"]
    j = blk.start + 3 * c
    x[j:j + 3] = NORMALS[other] - u                  # slot c holds another cell of colour c
    x[j + 3 - 3 * c + 3 * ((c + 1) % 4): j + 6 - 3 * c + 3 * ((c + 1) % 4)] = 0.01   # another slot: kept
    reset = proc._resets(x)
    assert reset.shape == (4, 4)
    assert reset[0, c] and reset.sum() == 1
    f = proc.f(x, None, 0.225)
    np.testing.assert_array_equal(f[j:j + 3], 0.0)
    a = np.exp(-0.225 / 133.0)
    keep = np.r_[blk.start:j, j + 3:lay.n]
    np.testing.assert_allclose(f[keep][8:], a * x[keep][8:], rtol=1e-14)
    F = proc.jacobian(x, None, 0.225)
    np.testing.assert_array_equal(F[j:j + 3, j:j + 3], 0.0)
    Q = proc.Q(x, None, 0.225)
    np.testing.assert_allclose(Q[j:j + 3, j:j + 3], np.deg2rad(10.2) ** 2 * np.eye(3), rtol=1e-9)
    Q[j:j + 3, j:j + 3] = 0.0
    assert np.all(Q[j:j + 3] == 0.0) and np.all(Q[:, j:j + 3] == 0.0)    # drawn afresh: no correlation
    # once reset (e = 0) the slot holds the current cell: no second reset
    assert not proc._resets(f).any()
    # the same receiver's cell held: no reset
    x[j:j + 3] = NORMALS[here] - u
    assert not proc._resets(x).any()


def test_refusals():
    with pytest.raises(ConfigError, match="attitude"):
        FiringClock(FiringClock.Params(direction_error_sd_deg=10.0), BuildContext(beacons=BEACONS))
    with pytest.raises(ConfigError, match="colours"):
        process(direction_error_slots=3)
    with pytest.raises(ConfigError, match="beacons"):
        process(direction_error_beacons=["B9"])
    with pytest.raises(Exception):
        FiringClock.Params(attitude_sd_deg=0.5, direction_error_sd_deg=-1.0)
    with pytest.raises(Exception):
        FiringClock.Params(attitude_sd_deg=0.5, direction_error_sd_deg=10.0, direction_error_tau_s=0.0)
    proc = process()
    with pytest.raises(ConfigError, match="sd_deg"):
        Direction(Direction.Params(arrival=True, error_state=True, receivers="truncated_icosahedron"), BuildContext(proc.layout, BEACONS, "us"))
    bare = FiringClock(FiringClock.Params(attitude_sd_deg=0.57), BuildContext(beacons=BEACONS))
    with pytest.raises(ConfigError, match="dir_err_B1"):
        direction(bare)
