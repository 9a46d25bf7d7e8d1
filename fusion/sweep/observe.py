"""Observations of the lockstep messages of N recordings (fusion.sweep.lockstep): per message of a sensor,
its bound measurement model and z (N, m) of every recording. The ``range`` model read by the ``line``
decoder is vectorised over messages and recordings (:func:`range_observations`); any other model is
observed message by message, recording by recording, through its own decoder and ``observe``."""
from __future__ import annotations

from typing import Any

import numpy as np

from fusion.api import MAX_MAGNITUDE, MalformedMessage, Message

from .lockstep import NotLockstep, _Stream, _values

__all__ = ["observations", "range_observations"]


def observations(sensor: Any, streams: list[_Stream], lines: np.ndarray) -> tuple[list, list]:
    """Per message of one sensor: its bound model (None: no observation) and z (N, m) of every recording."""
    fast = range_observations(sensor, streams, lines)
    if fast is not None:
        return fast
    s0 = streams[0]
    models: list = []
    zs: list = []
    for k in range(s0.t.size):
        got = []
        for s in streams:
            msg = Message(float(s.t[k]), s.name, _values(s, k, s.V[k]), int(lines[k]))
            try:
                dec = sensor.decoder.decode(msg)
                o = None if dec is None else sensor.model.observe(dec)
            except MalformedMessage:
                raise NotLockstep("a malformed message") from None
            if o is not None and o.R is not None:
                raise NotLockstep("an observation with its own R")
            got.append(o)
        if got[0] is None:
            if any(o is not None for o in got):
                raise NotLockstep("the seeds' recordings differ in timing or content")
            models.append(None)
            zs.append(None)
            continue
        sig = (got[0].t, getattr(got[0].model, "bound", id(type(got[0].model))), got[0].z.shape)
        if any(o is None or (o.t, getattr(o.model, "bound", id(type(o.model))), o.z.shape) != sig for o in got):
            raise NotLockstep("the seeds' recordings differ in timing or content")
        models.append(got[0].model)
        zs.append(np.stack([o.z for o in got]))
    return models, zs


def range_observations(sensor: Any, streams: list[_Stream], lines: np.ndarray) -> tuple[list, list] | None:
    """The ``range`` model's observations read by the ``line`` decoder, vectorised over messages and
    seeds (None when the sensor is something else): z is the ranges of ``beacon range ...`` pairs, with
    ``RangeModel.observe``'s checks of the numbers (>= 0, max_range, MAX_MAGNITUDE) over the whole array;
    the model's own ``observe`` binds each distinct beacon pattern and must give the same z there."""
    try:
        from fusion_plugins.decoders.line import LineDecoder
        from fusion_plugins.measurement.range import RangeModel
    except ImportError:                              # pragma: no cover
        return None
    model, dec = sensor.model, sensor.decoder
    if type(model) is not RangeModel or type(dec) is not LineDecoder or dec.params.numeric:
        return None
    s0 = streams[0]
    w = s0.width
    if w < 2 or w % 2 or sorted(s0.labels) != list(range(0, w, 2)) or s0.numeric != list(range(1, w, 2)):
        return None
    if dec.params.count is not None and dec.params.count != w:
        raise NotLockstep("a malformed message")
    Z = np.stack([s.V for s in streams])            # (N, K, m)
    mx = model.params.max_range
    if (Z < 0).any() or (mx is not None and (Z > mx).any()) or (Z > MAX_MAGNITUDE).any():
        raise NotLockstep("a malformed message")
    bound: dict[tuple, Any] = {}
    models: list = []
    lab_rows = list(zip(*(s0.labels[c] for c in range(0, w, 2))))
    for k, lab in enumerate(lab_rows):
        m = bound.get(lab)
        if m is None:
            msg = Message(float(s0.t[k]), s0.name, _values(s0, k, s0.V[k]), int(lines[k]))
            try:
                o = model.observe(dec.decode(msg))
            except MalformedMessage:
                raise NotLockstep("a malformed message") from None
            if o is None or o.R is not None or o.t != msg.t or not np.array_equal(o.z, s0.V[k]):
                return None                          # not the model this kernel knows: message by message
            m = bound[lab] = o.model
        models.append(m)
    return models, [Z[:, k] for k in range(Z.shape[1])]
