"""Exceptions raised by baarda.

All of them derive from :class:`BaardaError`, so a caller can catch everything baarda raises
on purpose with one ``except`` clause.
"""

from __future__ import annotations


class BaardaError(Exception):
    """Base class of all errors raised by baarda on purpose."""


class InputError(BaardaError):
    """Bad input file: ``str(err)`` is ``"{path}:{line}: {message}"``.

    ``line`` is 1-based (0 when the position is unknown); ``field`` optionally names the
    offending attribute or element. In a binary file ``offset`` (bytes from its start) says
    where: ``str(err)`` is then ``"{path}:byte {offset}: {message}"`` and ``line`` is 0.
    """

    def __init__(self, path, line: int, message: str, field: str | None = None,
                 offset: int | None = None):
        self.path = str(path)
        self.line = int(line or 0)
        self.message = message
        self.field = field
        self.offset = None if offset is None else int(offset)
        where = self.line if self.offset is None else f"byte {self.offset}"
        super().__init__(f"{self.path}:{where}: {message}")

    def __reduce__(self):
        return (type(self), (self.path, self.line, self.message, self.field, self.offset))


class DatumDefectError(BaardaError):
    """The normal equations have a rank defect that the datum does not remove.

    ``defect`` is the number of missing datum conditions; ``undetermined`` lists the unknowns
    (e.g. ``"P7.x"`` or orientation names) that the data cannot determine.
    """

    def __init__(self, defect: int, undetermined: list[str] | None = None, message: str = ""):
        self.defect = int(defect)
        self.undetermined = list(undetermined or [])
        if not message:
            message = f"datum defect {self.defect}"
            if self.undetermined:
                message += ": undetermined " + ", ".join(self.undetermined)
        self.message = message
        super().__init__(message)

    def __reduce__(self):
        return (type(self), (self.defect, self.undetermined, self.message))


class SingularError(BaardaError):
    """A matrix that must be regular (or positive definite) is singular."""
