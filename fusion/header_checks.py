"""A config against the recording it replays: where the config gives a value and the recording's header
(fusion.world) declares another for the same thing, the run is refused (exit 2) with one line naming both
values and where each came from, unless the config's ``prefer:`` says ``config`` for that quantity.

Quantities (``prefer:`` keys): ``magnetic_field`` (a magnetometer's ``field_ned`` or declination /
inclination / intensity against ``# SENSOR earth_field_ned``), ``beacons`` (``beacons:`` against ``# beacon
B: x y z``), ``receivers`` (a component's ``receivers:`` against ``# receiver N: x y z``), ``gravity``
(``process.gravity`` against ``# gravity``) and ``origin`` (a decoder's ``origin:`` against ``# origin``).
Values the config does not give are taken from the recording by the components themselves: nothing to
compare.
"""
from __future__ import annotations

import math
from typing import Any, Iterator

import numpy as np

from fusion.errors import ConfigError
from fusion.world import RecordingWorld

QUANTITIES = ("magnetic_field", "beacons", "receivers", "gravity", "origin")
#: a hand-typed field (declination and inclination to 0.5 deg, intensity to 1 %) agrees with its source
FIELD_ANGLE_DEG, FIELD_RELATIVE = 1.0, 0.02
#: the beacon tolerance of fusion.pipeline (a beacon surveyed to the centimetre)
BEACON_M = 0.01
#: a receiver's normal: well under the 37 deg between neighbours of the paper's array, over a typed 3-digit value
RECEIVER_DEG = 0.5
#: gravity: 1 mm/s^2, under the 0.05 m/s^2 between the equator and the poles and over a rounded figure
GRAVITY_MPS2 = 1e-3
#: origin: 1 m, a surveyed point against the metres of a GPS fix
ORIGIN_M = 1.0


def preferred(spec: Any) -> set[str]:
    """The quantities for which the config's ``prefer:`` says ``config``."""
    prefer = getattr(spec, "prefer", None)
    if prefer == "config":
        return set(QUANTITIES)
    return {k for k, v in (prefer or {}).items() if v == "config"}


def contradictions(system: Any, world: RecordingWorld | None, config: str = "config") -> list[tuple[str, str]]:
    """``(quantity, text)`` of each value the config gives that the recording's header contradicts."""
    if world is None:
        return []
    out = []
    for check in (_fields, _beacons, _receivers, _gravity, _origin):
        out += list(check(system, world, config))
    return out


def check(system: Any, world: RecordingWorld | None, config: str = "config") -> None:
    """ConfigError (exit 2) naming the first contradiction not covered by ``prefer: config``; the number of
    further ones is added."""
    skip = preferred(system.spec)
    found = [text for quantity, text in contradictions(system, world, config) if quantity not in skip]
    if found:
        more = f" (and {len(found) - 1} more)" if len(found) > 1 else ""
        raise ConfigError(found[0] + more)


def _v(a: Any) -> str:
    return "[" + ", ".join(f"{float(x):.6g}" for x in np.ravel(a)) + "]"


def _unless(quantity: str) -> str:
    return f"; fix one, or say which to use with `prefer: {{{quantity}: config}}` in the config"


def _components(system: Any) -> Iterator[tuple[str, str, Any]]:
    for name, s in system.sensors.items():
        for part, comp in (("decoder", s.decoder), ("preprocessor", s.preprocessor), ("model", s.model)):
            if comp is not None:
                yield name, part, comp


def _config_field(params: Any) -> np.ndarray | None:
    from fusion.geomag import field_ned

    if getattr(params, "field_ned", None) is not None:
        return np.asarray(params.field_ned, float)
    angles = [getattr(params, k, None) for k in ("declination_deg", "inclination_deg", "intensity")]
    return field_ned(*angles) if all(a is not None for a in angles) else None


def _fields(system: Any, world: RecordingWorld, config: str) -> Iterator[tuple[str, str]]:
    for name, part, comp in _components(system):
        mine = _config_field(getattr(comp, "params", None))
        theirs = world.mag_field.get(name)
        if mine is None or theirs is None:
            continue
        a, b = mine, theirs.value
        cos = float(a @ b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-300)
        angle = math.degrees(math.acos(min(1.0, max(-1.0, cos))))
        rel = abs(np.linalg.norm(a) - np.linalg.norm(b)) / max(float(np.linalg.norm(b)), 1e-300)
        if angle > FIELD_ANGLE_DEG or rel > FIELD_RELATIVE:
            yield "magnetic_field", (
                f"{config}: sensors.{name}.{part}: the magnetic field {_v(a)} (NED) contradicts the recording's "
                f"{_v(b)} declared at {theirs.where} ({angle:.1f} deg and {100 * rel:.0f} % apart)"
                + _unless("magnetic_field"))


def _beacons(system: Any, world: RecordingWorld, config: str) -> Iterator[tuple[str, str]]:
    configured = system.beacons
    if not configured:
        return
    for name, declared in world.beacons.items():
        mine = configured.get(name)
        if mine is None:
            yield "beacons", (f"{config}: beacons: the recording declares beacon {name} at {_v(declared.value)} "
                              f"({declared.where}) that the config does not define (defined: "
                              f"{', '.join(sorted(configured))})" + _unless("beacons"))
            continue
        d = len(mine)
        pos = declared.value
        theirs = pos[:d] if len(pos) >= d else np.r_[pos, np.zeros(d - len(pos))]
        gap = float(np.linalg.norm(theirs - mine))
        if not gap <= BEACON_M:
            yield "beacons", (f"{config}: beacons.{name}: {_v(mine)} in the config, {_v(pos)} in the recording "
                              f"({declared.where}): {gap:.3g} m apart" + _unless("beacons"))


def _receivers(system: Any, world: RecordingWorld, config: str) -> Iterator[tuple[str, str]]:
    if world.receivers is None:
        return
    theirs = world.receivers.value
    for name, part, comp in _components(system):
        if getattr(getattr(comp, "params", None), "receivers", None) is None or not hasattr(comp, "normals"):
            continue
        mine = np.asarray(comp.normals, float)
        where = f"{config}: sensors.{name}.{part}.receivers"
        if mine.shape != theirs.shape:
            yield "receivers", (f"{where}: {len(mine)} receivers in the config, {len(theirs)} in the recording "
                                f"({world.receivers.where})" + _unless("receivers"))
            continue
        angles = np.degrees(np.arccos(np.clip(np.sum(mine * theirs, axis=1), -1.0, 1.0)))
        bad = np.flatnonzero(angles > RECEIVER_DEG)
        if len(bad):
            r = int(bad[0])
            yield "receivers", (f"{where}: receiver {r + 1} is {_v(mine[r])} in the config and {_v(theirs[r])} in "
                                f"the recording ({world.receivers.where} and the lines after), {angles[r]:.1f} deg "
                                f"apart ({len(bad)} of {len(mine)} receivers differ: another array or numbering)"
                                + _unless("receivers"))


def _gravity(system: Any, world: RecordingWorld, config: str) -> Iterator[tuple[str, str]]:
    g = getattr(getattr(system.process, "params", None), "gravity", None)
    if g is None or world.gravity is None:
        return
    if abs(float(g) - world.gravity.value) > GRAVITY_MPS2:
        yield "gravity", (f"{config}: process.gravity: {float(g):.6g} m/s^2 in the config, {world.gravity.value:.6g} "
                          f"in the recording ({world.gravity.where})" + _unless("gravity"))


def _origin(system: Any, world: RecordingWorld, config: str) -> Iterator[tuple[str, str]]:
    if world.origin is None or not world.origin_declared:
        return
    lat0, lon0, h0 = world.origin.value
    for name, part, comp in _components(system):
        o = getattr(getattr(comp, "params", None), "origin", None)
        if o is None or not hasattr(o, "lat_deg"):
            continue
        import pymap3d

        n, e, d = pymap3d.geodetic2ned(o.lat_deg, o.lon_deg, o.alt_m, lat0, lon0, h0)
        gap = math.sqrt(n * n + e * e + d * d)
        if gap > ORIGIN_M:
            yield "origin", (f"{config}: sensors.{name}.{part}.origin: ({o.lat_deg:.7f}, {o.lon_deg:.7f}, {o.alt_m:g} m) "
                             f"in the config, ({lat0:.7f}, {lon0:.7f}, {h0:g} m) in the recording "
                             f"({world.origin.where}): {gap:.1f} m apart" + _unless("origin"))
