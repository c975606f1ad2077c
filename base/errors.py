"""The errors gridflow reports to a user: input it cannot work with.

Each names the file, key or argument and what was expected.  The command line reports
these (and the operating system's :class:`OSError`, and the estimator's
:class:`gridflow.estimator.InputError`) in one line with exit status 2; any other
exception is a bug in gridflow and ends with its traceback.
"""

from __future__ import annotations

__all__ = ["GridflowError", "UsageError", "ParameterError", "FileFormatError"]


class GridflowError(ValueError):
    """Input gridflow cannot work with; the message names it and what was expected."""


class UsageError(GridflowError):
    """Arguments or options that do not go together."""


class ParameterError(GridflowError):
    """A parameter of a generator or a scene out of range or of the wrong kind."""


class FileFormatError(GridflowError):
    """A file that is not what it should be (not a regular file, not the format, or keys
    of the wrong shape or type)."""
