"""The numbers of a system config, checked and assembled at wiring: a sensor's noise R, the initial mean and
covariance (by block), with the limits of fusion/config.py (MAX_INITIAL_SD). Errors are ConfigErrors naming
file:line and field."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from fusion.api import ConfigError, ProcessModel
from fusion.yamlsource import LocatedYAML

if TYPE_CHECKING:
    from fusion.config import NoiseSpec, SystemSpec

__all__ = ["noise_matrix", "initial_belief_values", "MAX_INITIAL_SD"]

#: Largest initial standard deviation (SI units); the reasons are at its use in fusion/config.py.
MAX_INITIAL_SD = 1e6
#: Largest |initial mean| of any element (m, s, ...): beyond Earth-centred positions (6.4e6 m) and Unix times
#: (1.8e9 s) by far, and far below where squares overflow.
MAX_INITIAL_MEAN = 1e12


def _noise_matrix(noise: NoiseSpec | float | list[float] | None, m: int, where: str) -> np.ndarray | None:
    if noise is None:
        return None
    if isinstance(noise, (int, float, list)):
        from fusion.config import NoiseSpec   # at call time: fusion.config imports this module

        noise = NoiseSpec(sd=noise)
    if noise.R is not None:
        R = _matrix(noise.R, f"{where}.R")
        if R.shape != (m, m):
            raise ConfigError(f"{where}.R: must be {m} x {m} for this measurement model, got {R.shape[0]} x {R.shape[1] if R.ndim > 1 else 1}")
        if not _positive_definite(R):
            raise ConfigError(f"{where}.R: must be symmetric positive definite")
        return R
    if noise.sd is not None:
        sd = np.atleast_1d(np.asarray(noise.sd, float))
        if sd.size not in (1, m):
            raise ConfigError(f"{where}.sd: needs {'1 value' if m == 1 else f'1 or {m} values'} for this measurement model, got {sd.size}")
        if np.any(sd <= 0):
            raise ConfigError(f"{where}.sd: standard deviations must be > 0")
        with np.errstate(over="ignore", under="ignore"):
            var = np.broadcast_to(sd, (m,)) ** 2
        if not (np.all(np.isfinite(var)) and np.all(var > 0)):
            raise ConfigError(f"{where}.sd: {sd.tolist()} squared is not a positive finite variance "
                              "(float64: 1e-150 < sd < 1e150)")
        return np.diag(var)
    return None


def _matrix(rows: list[list[float]], where: str) -> np.ndarray:
    """A matrix from YAML rows; ConfigError for rows of different lengths."""
    lengths = sorted({len(r) for r in rows})
    if len(lengths) > 1:
        raise ConfigError(f"{where}: rows of different lengths {lengths}; a matrix is a list of equal rows")
    return np.asarray(rows, float).reshape(len(rows), lengths[0] if lengths else 0)


def _positive_definite(A: np.ndarray) -> bool:
    """A symmetric positive definite (and finite: a Cholesky factor exists)."""
    if not (np.all(np.isfinite(A)) and np.allclose(A, A.T)):
        return False
    try:
        np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        return False
    return bool(np.all(np.linalg.eigvalsh(A) > 0))


def _fill_blocks(target: np.ndarray, values: dict[str, Any], layout, where) -> None:
    """Write ``{block: scalar or per-element values}`` into ``target`` (n,), naming the field on error."""
    for name, val in values.items():
        if name not in layout:
            raise ConfigError(f"{where(name)}: state has no block {name!r}; blocks are {[b.name for b in layout.blocks]}")
        sl = layout[name]
        v = np.atleast_1d(np.asarray(val, float))
        if v.size not in (1, sl.stop - sl.start):
            raise ConfigError(f"{where(name)}: block {name!r} has {sl.stop - sl.start} elements, got {v.size} values")
        target[sl] = v


def _initial(spec: SystemSpec, process: ProcessModel, doc: LocatedYAML | None) -> tuple[np.ndarray, np.ndarray]:
    lay = process.layout

    def where(*loc: Any) -> str:
        return doc.where(["initial", *loc]) if doc else "initial." + ".".join(map(str, loc))
    x0 = np.zeros(lay.n)
    for block in lay.blocks:
        if block.kind == "quaternion":
            x0[lay[block.name].start] = 1.0
    _fill_blocks(x0, spec.initial.mean, lay, lambda name: where("mean", name))
    huge = np.flatnonzero(np.abs(x0) > MAX_INITIAL_MEAN)
    if huge.size:
        name = next(b.name for b in lay.blocks if lay[b.name].start <= huge[0] < lay[b.name].stop)
        raise ConfigError(f"{where('mean', name)}: {x0[huge[0]]:g} is beyond {MAX_INITIAL_MEAN:g} in magnitude: no "
                          "state of a local frame, a clock or a sensor error is that large, and its squares would "
                          "overflow the filter's arithmetic")
    for block in lay.blocks:
        if block.kind == "quaternion" and not np.linalg.norm(x0[lay[block.name]]) > 1e-6:
            raise ConfigError(f"{where('mean', block.name)}: a quaternion needs a non-zero norm (e.g. [1, 0, 0, 0]), "
                              f"got {x0[lay[block.name]].tolist()}")
    if spec.initial.P is not None:
        P0 = _matrix(spec.initial.P, where("P"))
        if P0.ndim != 2 or P0.shape != (lay.n, lay.n):
            raise ConfigError(f"{where('P')}: must be {lay.n} x {lay.n} for the state {lay!r}, got {P0.shape}")
        big = np.flatnonzero(np.diagonal(P0) > MAX_INITIAL_SD ** 2)
        if big.size:
            raise ConfigError(f"{where('P')}: variance {np.diagonal(P0)[big[0]]:g} of {lay.names[big[0]]} above "
                              f"{MAX_INITIAL_SD ** 2:g} (sd {MAX_INITIAL_SD:g}): the filter would lose every digit "
                              "of the first update")
    else:
        sd = np.ones(lay.n)
        _fill_blocks(sd, spec.initial.sd, lay, lambda name: where("sd", name))
        missing = [b.name for b in lay.blocks if b.name not in spec.initial.sd]
        if missing and spec.initial.sd:
            raise ConfigError(f"{where('sd')}: no standard deviation for block(s) {missing}")
        if np.any(sd <= 0):
            raise ConfigError(f"{where('sd')}: standard deviations must be > 0")
        big = np.flatnonzero(sd > MAX_INITIAL_SD)
        if big.size:
            name = next(b.name for b in lay.blocks if lay[b.name].start <= big[0] < lay[b.name].stop)
            raise ConfigError(f"{where('sd', name)}: {sd[big[0]]:g} is above {MAX_INITIAL_SD:g}: with a measurement "
                              "of 1 cm sd the first update would keep no digit (P0 / R > 1 / eps); no prior "
                              "is that wide")
        P0 = np.diag(sd ** 2)
        if not np.all(np.diagonal(P0) > 0):
            raise ConfigError(f"{where('sd')}: standard deviations below 1e-150 square to a zero variance")
    if not _positive_definite(P0):
        raise ConfigError(f"{where('P')}: initial covariance must be symmetric positive definite")
    return x0, P0


noise_matrix = _noise_matrix
initial_belief_values = _initial
