"""Error types. Every user-facing error names the offending field."""


class StabjaxError(Exception):
    """Base class for errors reported to the user with a non-zero exit."""


class ValidationError(StabjaxError, ValueError):
    """Bad input: carries the name of the field (parameter, spec key) at fault."""

    def __init__(self, field: str, message: str):
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}")
