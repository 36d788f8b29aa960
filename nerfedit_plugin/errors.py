"""The one exception type for user errors: bad files, bad specs, bad options.

The CLI prints its message on one line and exits non-zero (traceback only with ``--verbose``).
Messages name the file or key and the problem, e.g. ``edit.json: handles[1].select.box.min: expected 3 numbers``.
"""


class NerfEditError(Exception):
    """A user-facing error: the message alone must tell the user what to fix."""


class OptionError(NerfEditError):
    """A config value out of range: ``option`` is the field's path in the config (``"resolution"``,
    ``"train.batch_rays"``), ``problem`` what is wrong with it.

    The message names the config class (``NerfConfig.resolution: must be ...``); the CLI rewrites it to the option's
    flag (``--field-options.resolution: must be ...``) or, for ``--load-config``, to the key in the file."""

    def __init__(self, config: object, option: str, problem: str) -> None:
        self.config_class = config if isinstance(config, type) else type(config)
        self.option, self.problem = option, problem
        super().__init__(f"{self.config_class.__name__}.{option}: {problem}")


def check_option(config: object, option: str, value: object, ok: bool, expected: str) -> None:
    """Raise :class:`OptionError` ``"{option}: must be {expected}, got {value!r}"`` unless ``ok`` (write the test so
    that NaN fails it: ``value > 0``, not ``not value <= 0``)."""
    if not ok:
        raise OptionError(config, option, f"must be {expected}, got {value!r}")
