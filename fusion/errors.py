"""The errors a user can act on, and the per-message ones a run counts (re-exported by fusion.api).

Kept free of numpy and pydantic so that ``fusion --help`` and the CLI's error reporting stay cheap.
"""
from __future__ import annotations

__all__ = ["FusionError", "ConfigError", "InputError", "MalformedMessage", "RejectedMessage"]


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
