"""The one exception type for user errors: bad files, bad specs, bad options.

The CLI prints its message on one line and exits non-zero (traceback only with ``--verbose``).
Messages name the file or key and the problem, e.g. ``edit.json: handles[1].select.box.min: expected 3 numbers``.
"""


class NerfEditError(Exception):
    """A user-facing error: the message alone must tell the user what to fix."""
