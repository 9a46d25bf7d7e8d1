"""The kit for plugin authors: contract checks per kind, reference models, and helpers that select
only your own components.

Run the checks the built-ins pass on your component, from your own test suite::

    from fusion import testing
    from fusion.api import StateLayout
    from fusion_baro.plugin import Barometer

    def test_barometer_contract():
        testing.check_measurement(Barometer, {"offset": 2.0}, StateLayout.parse("p:3 v:3"))

    @testing.parametrize_registered("measurement", package="fusion_baro")   # yours only
    def test_each_of_mine_declares_itself(name):
        testing.check_component(testing.registry_class("measurement", name))

``check_measurement(cls, params, layout, message=...)``, ``check_process(cls, params)``,
``check_filter(cls, params)``, ``check_gate(cls, params)``: build the component as a config would (a build
error is raised, never skipped) and check vectorisation over leading axes, the Jacobian against a numerical one (always, analytic
or not), ``Params`` forbidding unknown keys, name, docstring and capability spelling
(:func:`check_component`). Every ``check_*`` raises AssertionError with the worst mismatch, and returns
it when it passes. Importing this module does not import pytest (only :func:`parametrize_registered`
does).

Reference models (test-only, not registered): :class:`ConstantVelocity`, :class:`PositionMeasurement`,
:class:`RangeMeasurement`, :class:`RejectAll`; :func:`reference_kf` is a textbook Kalman filter written
independently of the plugins.
"""
from __future__ import annotations

from .filters import check_filter_interface, check_filter_linear_exactness
from .gates import check_gate
from .models import (check_component, check_filter, check_measurement, check_measurement_jacobian,
                     check_measurement_vectorised, check_process, check_process_jacobian, check_process_vectorised)
from .numeric import random_states, reference_jacobian
from .reference import ConstantVelocity, PositionMeasurement, RangeMeasurement, RejectAll, nees, reference_kf
from .selection import build, parametrize_registered, registered, registry_class

__all__ = [
    "ConstantVelocity", "PositionMeasurement", "RangeMeasurement", "RejectAll", "reference_kf",
    "registered", "registry_class", "build", "parametrize_registered", "random_states", "reference_jacobian",
    "nees", "check_component", "check_measurement", "check_process", "check_filter", "check_gate",
    "check_filter_linear_exactness", "check_filter_interface", "check_process_vectorised",
    "check_process_jacobian", "check_measurement_vectorised", "check_measurement_jacobian",
]
