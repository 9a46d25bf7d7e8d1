"""A flight's events for the recording's header (``# message T: ...``): arming, disarming, mode changes and
failsafes, so a user can choose ``--start``/``--end`` and a results page can tell the flight from the
ground. Each text starts with one word a reader can match: ``ARMED``, ``DISARMED``, ``MODE``, ``FAILSAFE``,
``EVENT``, ``ERROR``.

- ArduPilot DataFlash: ``EV`` (``Id``: ArduPilot's LogEvent numbers, libraries/AP_Logger/AP_Logger.h),
  ``MODE`` (``Mode``/``ModeNum``, named by pymavlink's mode tables for the vehicle), ``ERR`` (``Subsys``,
  ``ECode``: LogErrorSubsystem, same header).
- PX4 ULog: ``vehicle_status`` changes of ``arming_state`` (2 armed), ``nav_state`` (the mode,
  vehicle_status.msg NAVIGATION_STATE_*) and ``failsafe``.
"""
from __future__ import annotations

import numpy as np

# AP_Logger LogEvent (the ones a user chooses a span by; others are written by number)
AP_EVENTS = {10: "ARMED", 11: "DISARMED", 15: "EVENT auto armed", 16: "EVENT takeoff", 17: "EVENT land complete maybe",
             18: "EVENT land complete", 19: "FAILSAFE lost GPS", 21: "EVENT flip start", 22: "EVENT flip end",
             25: "EVENT set home", 28: "EVENT not landed", 54: "FAILSAFE motors emergency stopped"}
# AP_Logger LogErrorSubsystem
AP_ERR_SUBSYS = {2: "radio", 3: "compass", 4: "optflow", 5: "FAILSAFE radio", 6: "FAILSAFE battery",
                 7: "FAILSAFE GPS", 8: "FAILSAFE GCS", 9: "FAILSAFE fence", 10: "flight mode", 11: "GPS",
                 12: "crash check", 13: "flip", 14: "autotune", 15: "parachutes", 16: "EKF check",
                 17: "FAILSAFE EKF inav", 18: "baro", 19: "CPU", 20: "FAILSAFE ADSB", 21: "terrain",
                 22: "navigation", 23: "FAILSAFE terrain", 24: "EKF primary", 25: "thrust loss check",
                 26: "FAILSAFE sensor", 27: "FAILSAFE leak", 28: "pilot input", 29: "FAILSAFE vibration"}
# PX4 vehicle_status.msg NAVIGATION_STATE_*
PX4_NAV = {0: "MANUAL", 1: "ALTCTL", 2: "POSCTL", 3: "AUTO_MISSION", 4: "AUTO_LOITER", 5: "AUTO_RTL",
           6: "AUTO_RCRECOVER", 7: "AUTO_RTGS", 8: "AUTO_LANDENGFAIL", 9: "AUTO_LANDGPSFAIL", 10: "ACRO",
           11: "UNUSED", 12: "DESCEND", 13: "TERMINATION", 14: "OFFBOARD", 15: "STAB", 16: "RATTITUDE",
           17: "AUTO_TAKEOFF", 18: "AUTO_LAND", 19: "AUTO_FOLLOW_TARGET", 20: "AUTO_PRECLAND", 21: "ORBIT",
           22: "AUTO_VTOL_TAKEOFF"}
PX4_ARMED = 2   # vehicle_status ARMING_STATE_ARMED


def _ap_mode_names(vehicle: str) -> dict[int, str]:
    """ArduPilot mode number -> name for the vehicle (pymavlink's tables; copter when unknown)."""
    from pymavlink import mavutil

    v = vehicle.lower()
    table = (mavutil.mode_mapping_apm if "plane" in v else mavutil.mode_mapping_rover if "rover" in v
             else mavutil.mode_mapping_sub if "sub" in v else mavutil.mode_mapping_acm)
    return {int(k): str(n) for k, n in table.items()}


def dataflash_events(rows: dict, vehicle: str) -> list[tuple[float, str]]:
    """(t s, text) of the EV, MODE and ERR tables (columns as fusion.importers.dataflash_tables reads them)."""
    out: list[tuple[float, str]] = []
    ev = rows.get("EV")
    if ev is not None and "Id" in ev:
        for t, i in zip(ev["t"].tolist(), np.asarray(ev["Id"]).tolist()):
            out.append((t, AP_EVENTS.get(int(i), f"EVENT {int(i)}")))
    mode = rows.get("MODE")
    if mode is not None:
        names = _ap_mode_names(vehicle)
        col = "ModeNum" if "ModeNum" in mode else "Mode" if "Mode" in mode else None
        if col is not None:
            for t, m in zip(mode["t"].tolist(), np.asarray(mode[col]).tolist()):
                out.append((t, f"MODE {names.get(int(m), str(int(m)))}"))
    err = rows.get("ERR")
    if err is not None and "Subsys" in err:
        for t, s, c in zip(err["t"].tolist(), np.asarray(err["Subsys"]).tolist(),
                           np.asarray(err.get("ECode", np.zeros(len(err["t"])))).tolist()):
            name = AP_ERR_SUBSYS.get(int(s), f"subsystem {int(s)}")
            kind = "FAILSAFE" if name.startswith("FAILSAFE") else "ERROR"
            name = name.removeprefix("FAILSAFE ")
            out.append((t, f"{kind} {name} " + ("resolved" if int(c) == 0 else f"code {int(c)}")))
    return out


def px4_events(status, tcol) -> list[tuple[float, str]]:
    """(t s, text) of the changes of a ``vehicle_status`` topic's arming, mode and failsafe (pyulog data)."""
    if status is None:
        return []
    d = status.data
    t = tcol(status)
    out: list[tuple[float, str]] = []
    for field, say in (("arming_state", lambda v: "ARMED" if v == PX4_ARMED else "DISARMED"),
                       ("nav_state", lambda v: f"MODE {PX4_NAV.get(v, str(v))}"),
                       ("failsafe", lambda v: "FAILSAFE on" if v else "FAILSAFE off")):
        if field not in d:
            continue
        v = np.asarray(d[field]).astype(int)
        change = np.flatnonzero(np.concatenate([[True], v[1:] != v[:-1]]))
        for i in change.tolist():
            if field == "arming_state" and i == 0 and v[0] != PX4_ARMED:
                continue            # disarmed at the start: not an event
            if field == "failsafe" and i == 0 and not v[0]:
                continue
            out.append((float(t[i]), say(int(v[i]))))
    return out


def in_flight(messages: list[tuple[float, str]]) -> list[tuple[float, float]]:
    """The spans (s) between each ``ARMED`` and the next ``DISARMED`` (to +inf when it never disarms)."""
    spans, since = [], None
    for t, text in sorted(messages):
        if text.startswith("ARMED") and since is None:
            since = t
        elif text.startswith("DISARMED") and since is not None:
            spans.append((since, t))
            since = None
    if since is not None:
        spans.append((since, float("inf")))
    return spans
