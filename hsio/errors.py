"""Errors raised by hsio. Each names what is wrong and where."""


class HsioError(Exception):
    """Base class of every error hsio raises on purpose."""


class ConfigError(HsioError):
    """A configuration (TOML file, keyword, structure name) is invalid."""


class RecordError(HsioError):
    """A ground-motion record or data file cannot be read or holds bad values."""


class LimitError(HsioError):
    """A command was refused because it is beyond an actuator limit.

    Nothing was sent: the actuator holds its last position.
    """


class CommunicationError(HsioError):
    """A controller did not answer, answered with an error, or the link dropped."""


class InterlockError(HsioError):
    """A controller reports an interlock (limit trip, fault) and holds."""
