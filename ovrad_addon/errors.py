"""The one exception type for errors a user can cause (bad input, impossible settings)."""


class OvradError(ValueError):
    """Raised for input the engine cannot use; the message says what to do about it."""
