"""The errors a user can act on, and the per-message ones a run counts (re-exported by fusion.api).

Kept free of numpy and pydantic so that ``fusion --help`` and the CLI's error reporting stay cheap.
"""
from __future__ import annotations

__all__ = ["FusionError", "ConfigError", "InputError", "MalformedMessage", "RejectedMessage", "ModelFault"]


class FusionError(Exception):
    """Base of the errors a user can act on (the CLI prints them in one line, exit code 2)."""


class ConfigError(FusionError):
    """A config or scenario is wrong: the message names file, field path (and YAML line) and what is valid."""


class InputError(FusionError):
    """An input (recording, serial port) cannot be used at all: missing, binary, wrong encoding, dead port."""


class MalformedMessage(ValueError):
    """One message is malformed (bad number, wrong field count, bad checksum): counted and skipped."""


class RejectedMessage(MalformedMessage):
    """A well-formed message outside the sensor's limits (a NaN or an out-of-range IMU sample): counted as
    rejected and not used."""


class ModelFault(Exception):
    """A model returned what the filter cannot use: the wrong shape or type, NaN or inf at a finite state, a
    process noise Q that is not symmetric positive semi-definite (raised by the filters, which check each
    value a model returns where they receive it). The run treats it as the model failing, as if the model
    had raised: a measurement model's update is lost (counted malformed, the model named), a process
    model's prediction held (and the run stopped after several in a row). The message says what was wrong
    (e.g. ``f returned shape (2,) at the belief's mean, expected (3,)``); the run adds the model's name."""
