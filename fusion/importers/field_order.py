"""The order in which the project's components read a sensor's values, for importers whose user names the
columns (a CSV mapping): a mapping that lists a known set of names in another order is written in the
order the component reads (``fusion run`` refuses a ``# fields`` line naming them in another order, since
values are read by position).

The known orders are the registered processes' ``input_fields`` (``ax ay az gx gy gz`` of the INS), the
``fields`` components declare, the ``gps_fields`` decoder's layouts and the attitude quaternion
``qw qx qy qz``.
"""
from __future__ import annotations

from functools import lru_cache

from fusion.importers.gps_decoder import LAYOUTS

#: Orders every build knows, whatever plugins are installed.
_FIXED = (("mx", "my", "mz"), ("qw", "qx", "qy", "qz"), ("px", "py", "pz"), ("vx", "vy", "vz"))


@lru_cache(maxsize=1)
def known_orders() -> tuple[tuple[str, ...], ...]:
    """Every order of value names a component of the default registry reads (see the module)."""
    out: list[tuple[str, ...]] = list(_FIXED) + [tuple(v) for v in LAYOUTS.values()]
    try:
        from fusion.registry import default_registry

        reg = default_registry()
        for kind in ("process", "measurement", "decoder"):
            for e in reg.entries(kind):
                for attr in ("input_fields", "fields"):
                    names = getattr(e.cls, attr, None)
                    if isinstance(names, tuple) and names and all(isinstance(n, str) for n in names):
                        out.append(tuple(names))
    except Exception:   # a broken third-party plugin must not stop an import: the fixed orders still apply
        pass
    return tuple(dict.fromkeys(out))


def reading_order(names: tuple[str, ...]) -> tuple[str, ...] | None:
    """The order a component reads ``names`` in, when ``names`` is that set in another order; None when
    ``names`` is already in a known order or is no known set."""
    names = tuple(names)
    if len(set(names)) != len(names):
        return None
    for order in known_orders():
        if order == names:
            return None
    for order in known_orders():
        if len(order) == len(names) and set(order) == set(names):
            return order
    return None
