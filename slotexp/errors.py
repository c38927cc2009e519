"""Errors the user can fix; the CLI prints them as one line and exits non-zero."""

from __future__ import annotations


class UserError(Exception):
    """Bad input that is the user's to fix (a path, a file's content, a combination of options)."""
