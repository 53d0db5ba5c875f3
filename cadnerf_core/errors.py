"""Errors the core raises on purpose: each says what is wrong and what to do."""

from __future__ import annotations


class CadNerfError(Exception):
    """Base class: an expected failure with a message meant for a person."""


class InputError(CadNerfError):
    """A photo, mask, mesh or setting a user gave cannot be used.

    ``item`` names the offending input (a photo's file name, a mesh path, a field).
    """

    def __init__(self, message: str, item: str | None = None, hint: str | None = None) -> None:
        self.item = item
        self.hint = hint
        text = f"{item}: {message}" if item else message
        if hint:
            text = f"{text} ({hint})"
        super().__init__(text)


class MeshError(InputError):
    """A mesh file is missing, unreadable or unusable."""


class LibraryError(CadNerfError):
    """The CAD library is missing, stale or damaged; the message names the file."""


class JobCancelled(CadNerfError):
    """The job was cancelled between two steps."""
