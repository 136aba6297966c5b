"""Exception types. The CLI prints these without a traceback and exits non-zero."""


class OGSceneError(ValueError):
    """Base class for errors caused by bad input (files, values, configuration)."""


class DataError(OGSceneError):
    """A data file is missing, unreadable, truncated or inconsistent. The message names the file."""


class ModelError(OGSceneError):
    """A user-supplied model (ONNX file, HTTP endpoint) is missing, malformed or failing."""


class ConfigError(OGSceneError):
    """A configuration key or value is unknown or invalid."""
