"""What ``fusion import`` adds to a flight log (PX4 ULog, ArduPilot DataFlash) so a config runs on it as is.

- **One origin.** The recording's ``origin`` is the first GPS fix that the ``gps_fields`` decoder accepts
  (fix type >= 3, >= 6 satellites), the origin a config's local NED frame takes (paper 002 eqs. 5-6, no
  static period). The ``reference`` positions are re-expressed about it, so the filter's ``p`` and the
  onboard estimator's compare element by element: exactly (pymap3d, WGS84) when the estimator's own origin
  is on the globe (PX4 ``ref_lat/ref_lon/ref_alt`` with ``xy_global``, ArduPilot ``ORGN``), else by the
  reference's own position at the first fix (its frame is not tied to the globe: only motion compares).
- **The onboard attitude at the start**, as one ``initial_attitude`` line (``qw qx qy qz``, body FRD to
  NED) at the first reference time, unless the importer gave its own (PX4: the first valid attitude, which
  a reference that starts late, when the EKF's position becomes valid, does not move): a config that starts in flight takes its attitude from it (docs/import.md,
  "Starting in flight"). It is the only reference value a config may use, and only to start.
"""
from __future__ import annotations

import numpy as np

from fusion.api import ImportedLog, Stream
from fusion.importers.common import F32
from fusion.importers.gps_decoder import LAYOUTS, MIN_FIX, MIN_SATELLITES


def gps_origin(gps: Stream) -> tuple[float, float, float, float] | None:
    """(t s, lat deg, lon deg, alt m AMSL) of the first fix the ``gps_fields`` decoder accepts by default."""
    if gps.values is None or len(gps) == 0 or tuple(gps.fields) not in LAYOUTS.values():
        return None
    f = list(gps.fields)
    v = np.asarray(gps.values, float)
    fix = v[:, f.index("fix")]
    # fix types are codes, not a scale: 7 and 8 (PX4 8: extrapolated) are no measured fix (gps_decoder)
    ok = np.flatnonzero((fix >= MIN_FIX) & (fix <= 6) & (v[:, f.index("nsat")] >= MIN_SATELLITES))
    if ok.size == 0:
        return None
    i = ok[0]
    return float(gps.t[i]), float(v[i, 0]), float(v[i, 1]), float(v[i, 2])


def _refer(ref: Stream, origin: tuple[float, float, float, float]) -> None:
    """Re-express the reference's px py pz (NED, m) about ``origin`` (t, lat, lon, alt) in place."""
    import pymap3d

    names = list(ref.fields)
    cols = [names.index(c) for c in ("px", "py", "pz") if c in names]
    if not cols:
        return
    v = np.array(ref.values, float)
    ekf = ref.meta.pop("ekf_origin", None)
    t0, lat0, lon0, alt0 = origin
    if ekf is not None and len(cols) == 3:
        elat, elon, ealt = (float(x) for x in ekf.split())
        lat, lon, alt = pymap3d.ned2geodetic(v[:, cols[0]], v[:, cols[1]], v[:, cols[2]], elat, elon, ealt)
        n, e, d = pymap3d.geodetic2ned(lat, lon, alt, lat0, lon0, alt0)
        v[:, cols[0]], v[:, cols[1]], v[:, cols[2]] = n, e, d
        how = f"about the recording's origin, from the estimator's own ({ekf}) by WGS84"
    else:
        at = [float(np.interp(t0, ref.t, v[:, c])) for c in cols]
        for c, a in zip(cols, at):
            v[:, c] -= a
        shift = " ".join(f"{names[c]} {-a:+.3f}" for c, a in zip(cols, at))
        how = (f"about the recording's origin: the estimator's frame is not tied to the globe, so its position "
               f"at the first GPS fix (t {t0:.3f} s) is taken as the origin ({shift} m added)")
    ref.values = v
    ref.meta["frame"] = "NED " + how + "; q body FRD to NED, [w x y z]"


def prepare(log: ImportedLog) -> None:
    """Set ``log.meta['origin']`` to the first accepted GPS fix, refer the reference to it, add the
    ``initial_attitude`` stream (see the module). Logs without geodetic GPS fields are left as they are."""
    gps = next((s for s in log.streams if s.sensor == "gps" and len(s)), None)
    ref = next((s for s in log.streams if s.sensor == "reference" and len(s)), None)
    origin = gps_origin(gps) if gps is not None else None
    if gps is not None and tuple(gps.fields) not in LAYOUTS.values():
        log.notes.append(f"gps: fields {' '.join(gps.fields)} are not a layout the gps_fields decoder reads "
                         "(the real-vehicle configs): import with --gps nmea and use the nmea decoder")
    if origin is not None:
        log.meta["origin"] = f"{origin[1]:.9f} {origin[2]:.9f} {origin[3]:.3f}"
        log.meta["origin_source"] = (f"the first GPS fix with fix type >= {MIN_FIX} and >= {MIN_SATELLITES} "
                                     f"satellites (t {origin[0]:.3f} s), the origin the gps_fields decoder takes")
        if ref is not None and ref.values is not None:
            _refer(ref, origin)
    elif ref is not None and "ekf_origin" in ref.meta:
        log.meta.setdefault("origin", ref.meta["ekf_origin"])
        log.meta.setdefault("origin_source", "the onboard estimator's origin (no accepted GPS fix imported)")
    if origin is not None and _attitude_at_start(log, ref, origin[0]):
        return
    given = any(s.sensor == "initial_attitude" and len(s) for s in log.streams)   # the importer's own (PX4)
    if not given and ref is not None and ref.values is not None and {"qw", "qx", "qy", "qz"} <= set(ref.fields):
        idx = [list(ref.fields).index(c) for c in ("qw", "qx", "qy", "qz")]
        q = np.asarray(ref.values, float)[:1, idx]
        log.streams.append(Stream("initial_attitude", ("qw", "qx", "qy", "qz"), np.asarray(ref.t[:1], float), q,
                                  (F32,) * 4, {"source": "the first reference attitude (body FRD to NED), for a "
                                               "config that starts in flight"}))


def _attitude_at_start(log: ImportedLog, ref: Stream | None, t_fix: float) -> bool:
    """Replace the ``initial_attitude`` line by the reference attitude at the first accepted fix ``t_fix``
    (s), written 1 us before it: a config with ``initial.from_sensor: gps`` starts at the IMU sample after that
    fix, and the onboard attitude of the log's first sample (maybe a minute of flight earlier) is not the
    vehicle's then. False (nothing changed) when the reference has no attitude at or before the fix."""
    from fusion.importers.common import slerp_to

    if ref is None or ref.values is None or not {"qw", "qx", "qy", "qz"} <= set(ref.fields) or ref.t[0] > t_fix:
        return False
    idx = [list(ref.fields).index(c) for c in ("qw", "qx", "qy", "qz")]
    q = slerp_to(np.asarray(ref.t, float), np.asarray(ref.values, float)[:, idx], np.array([t_fix]))
    t = round(t_fix, 6) - 1e-6
    log.streams = [s for s in log.streams if s.sensor != "initial_attitude"]
    log.streams.append(Stream("initial_attitude", ("qw", "qx", "qy", "qz"), np.array([t]), q, (F32,) * 4,
                              {"source": f"the reference attitude (body FRD to NED) at the first accepted GPS fix "
                               f"(t {t_fix:.3f} s), where a config with initial.from_sensor: gps starts"}))
    return True
