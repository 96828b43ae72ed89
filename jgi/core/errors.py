"""Errors a user's input can raise, below every layer that checks it."""

from __future__ import annotations


class ParameterError(ValueError):
    """A bad estimator name or parameter (names the estimator, the key and what is allowed)."""


class CheckpointError(ValueError):
    """A checkpoint folder that holds another render (names the folder and what differs)."""
