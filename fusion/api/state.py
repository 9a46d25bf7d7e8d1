"""State types: named blocks of the state vector (``StateLayout``) and the Gaussian ``Belief``.

Conventions (DESIGN.md): SI units; quaternions Hamilton, scalar first ``[w x y z]``, body-to-navigation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Literal, Mapping, Sequence

import numpy as np

__all__ = ["Block", "StateLayout", "Belief", "BlockKind"]

BlockKind = Literal["vector", "quaternion", "angle"]

_AXES = {"vector": "xyz", "quaternion": "wxyz"}


@dataclass(frozen=True)
class Block:
    """A named block of the state: ``p:3`` (vector), ``q:4`` (quaternion), ``psi:1`` (angle).

    ``unit``: for a quaternion block, whether the filters keep it at unit norm (paper 000 eq. 50: the
    mean renormalised after every predict and update); False leaves the norm to a pseudo-observation
    (paper 002 eq. 9, ``quat_norm``). Ignored for other kinds."""

    name: str
    size: int
    kind: BlockKind = "vector"
    unit: bool = True

    def element_names(self) -> tuple[str, ...]:
        """Names of the elements: ``px py pz`` (vector <= 3), ``qw qx qy qz`` (quaternion), else ``b0 b1 ..``."""
        if self.kind == "quaternion":
            return tuple(self.name + a for a in "wxyz")
        if self.kind == "vector" and self.size <= 3:
            return tuple(self.name + a for a in "xyz"[: self.size])
        if self.size == 1:
            return (self.name,)
        return tuple(f"{self.name}{i}" for i in range(self.size))


#: Output columns besides the state's elements (fusion.outputs): no state element may be named so.
RESERVED_NAMES = frozenset({"t", "reason", "sensor"})


class StateLayout:
    """Ordered named blocks; everything outside a model addresses the state by block name.

    >>> lay = StateLayout.parse("p:3 v:3 q:4:quaternion")
    >>> lay.n, lay["v"], lay.names[:4]
    (10, slice(3, 6, None), ('px', 'py', 'pz', 'vx'))
    """

    def __init__(self, blocks: Sequence[Block]):
        self.blocks: tuple[Block, ...] = tuple(blocks)
        names = [b.name for b in self.blocks]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate block names in state layout: {names}")
        self._slices: dict[str, slice] = {}
        i = 0
        for b in self.blocks:
            self._slices[b.name] = slice(i, i + b.size)
            i += b.size
        self.n: int = i
        self.names: tuple[str, ...] = tuple(e for b in self.blocks for e in b.element_names())
        # Element names are the columns of the outputs (t, px, ..., sd_px, ..., reason, sensor) and the keys
        # of truth and summaries: one that repeats or is taken by the output would silently overwrite another.
        seen: set[str] = set()
        for e in self.names:
            if e in seen:
                raise ValueError(f"state element name {e!r} appears twice (blocks {names}): rename a block")
            if e in RESERVED_NAMES or e.startswith("sd_"):
                raise ValueError(f"state element name {e!r} is taken by the outputs (t, reason, sensor and the "
                                 "sd_ columns): rename its block")
            seen.add(e)
        #: The quaternion blocks kept at unit norm, as slices: what :meth:`normalize` renormalises.
        self.unit_quaternions: tuple[slice, ...] = tuple(
            self._slices[b.name] for b in self.blocks if b.kind == "quaternion" and b.unit)

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """States (..., n) with every unit quaternion block (:attr:`unit_quaternions`) divided by its norm:
        a new array; ``x`` itself when the layout has none. The filters apply it to every predicted and
        updated mean, so no filter needs to remember a process model for it."""
        if not self.unit_quaternions:
            return x
        x = np.array(x, dtype=float, copy=True)
        for sl in self.unit_quaternions:
            q = x[..., sl]
            if x.ndim == 1:
                q /= math.sqrt(float(q @ q))
            else:
                q /= np.sqrt((q * q).sum(axis=-1, keepdims=True))
        return x

    def with_unit(self, unit: bool) -> "StateLayout":
        """The same blocks with every quaternion block's ``unit`` set to ``unit``."""
        return StateLayout([replace(b, unit=unit) if b.kind == "quaternion" else b for b in self.blocks])

    @classmethod
    def parse(cls, spec: str) -> "StateLayout":
        """Parse ``"name:size[:kind] ..."``, e.g. ``"p:3 v:3 q:4:quaternion ba:3 bw:3"``."""
        blocks = []
        for tok in spec.split():
            parts = tok.split(":")
            kind = parts[2] if len(parts) > 2 else ("quaternion" if parts[0] == "q" and parts[1] == "4" else "vector")
            blocks.append(Block(parts[0], int(parts[1]), kind))  # type: ignore[arg-type]
        return cls(blocks)

    def __getitem__(self, name: str) -> slice:
        try:
            return self._slices[name]
        except KeyError:
            raise KeyError(f"state has no block {name!r}; blocks are {list(self._slices)}") from None

    def __contains__(self, name: str) -> bool:
        return name in self._slices

    def __len__(self) -> int:
        return self.n

    def __eq__(self, other: object) -> bool:
        return isinstance(other, StateLayout) and self.blocks == other.blocks

    def __hash__(self) -> int:
        return hash(self.blocks)

    def __repr__(self) -> str:
        return "StateLayout(" + " ".join(f"{b.name}:{b.size}:{b.kind}" for b in self.blocks) + ")"

    def block(self, name: str) -> Block:
        for b in self.blocks:
            if b.name == name:
                return b
        raise KeyError(f"state has no block {name!r}; blocks are {list(self._slices)}")

    def element_index(self, element: str) -> int:
        """Index of a named element (``"vy"``)."""
        try:
            return self.names.index(element)
        except ValueError:
            raise KeyError(f"state has no element {element!r}; elements are {list(self.names)}") from None

    def vector(self, values: Mapping[str, Any], default: float = 0.0) -> np.ndarray:
        """Assemble a full state vector from ``{block: values}`` (scalar broadcast to the block)."""
        x = np.full(self.n, default, dtype=float)
        for name, val in values.items():
            sl = self[name]
            arr = np.broadcast_to(np.asarray(val, dtype=float), (sl.stop - sl.start,))
            x[sl] = arr
        return x


@dataclass(frozen=True, init=False)
class Belief:
    """Gaussian belief at time ``t``: mean ``x`` (n,) and either covariance ``P`` (n, n) or its
    lower Cholesky factor ``S`` (P = S S^T, used by the square-root UKF). Immutable: filters return new ones.

    ``events``: what the filter reported while making this belief (a covariance it had to repair, a failed
    downdate: ``fusion.api.Event`` with kind ``not_positive_definite``), so that a prediction, which
    returns a belief, hands them to the run as a value; the run reports them and drops them from the
    belief it keeps. Empty almost always.

    The constructor writes the fields directly: a frozen dataclass's own ``__init__`` (one
    ``object.__setattr__`` a field) is slow, and filters build one or two beliefs a step."""

    t: float
    x: np.ndarray
    P: np.ndarray | None = None
    S: np.ndarray | None = None
    events: tuple = ()

    def __init__(self, t: float, x: np.ndarray, P: np.ndarray | None = None, S: np.ndarray | None = None,
                 events: tuple = ()):
        if P is None and S is None:
            raise ValueError("a Belief needs P or S")
        self.__dict__.update(t=t, x=x, P=P, S=S, events=events)

    @property
    def cov(self) -> np.ndarray:
        """The covariance P (computed from S when the belief is square-root)."""
        if self.P is not None:
            return self.P
        return self.S @ self.S.T  # type: ignore[union-attr]

    @property
    def sd(self) -> np.ndarray:
        """Standard deviations sqrt(diag P)."""
        if self.S is not None and self.P is None:
            return np.sqrt(np.einsum("ij,ij->i", self.S, self.S))
        # np.clip(d, 0.0, None) is np.maximum(d, 0.0) (numpy's _methods._clip with no upper bound), without its
        # three Python-level wrappers (most of its cost; called per estimate by the run's statistics and sinks)
        return np.sqrt(np.maximum(np.diagonal(self.P), 0.0))  # type: ignore[arg-type]

    def with_(self, **changes: Any) -> "Belief":
        return replace(self, **changes)
