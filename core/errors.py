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
    (e.g. ``"P7.x"`` or orientation names) that the data cannot determine; ``local``: the
    adjustment found them undetermined by too few observations to them (singular normal
    equations), not by a datum the block lacks as a whole.
    """

    def __init__(self, defect: int, undetermined: list[str] | None = None, message: str = "",
                 local: bool = False):
        self.defect = int(defect)
        self.undetermined = list(undetermined or [])
        self.local = bool(local)
        if not message:
            message = f"datum defect {self.defect}"
            if self.undetermined:
                message += ": undetermined " + ", ".join(self.undetermined)
        self.message = message
        super().__init__(message)

    def __reduce__(self):
        return (type(self), (self.defect, self.undetermined, self.message, self.local))


class SingularError(BaardaError):
    """A matrix that must be regular (or positive definite) is singular.

    When a factorisation breaks down at a pivot, ``unknown`` names the unknown there (e.g.
    ``"P7.x"``) and ``index`` is its column in the matrix; both are None otherwise.
    """

    def __init__(self, message: str = "", unknown: str | None = None, index: int | None = None):
        self.unknown = unknown
        self.index = None if index is None else int(index)
        if not message:
            message = f"normal matrix is singular: {unknown} is not determined by the observations"
        self.message = message
        super().__init__(message)

    def __reduce__(self):
        return (type(self), (self.message, self.unknown, self.index))


class OptionError(BaardaError, ValueError):
    """An argument outside the values a function accepts.

    ``option`` names the argument (``"solver"``, ``"alpha"``, a recipe key), ``value`` is what
    was given and ``allowed`` the accepted values (a tuple; empty when a range is meant, which
    the message states). A :class:`ValueError` too, as Python's convention for bad values.
    """

    def __init__(self, option: str, value, allowed=(), message: str = ""):
        self.option = str(option)
        self.value = value
        self.allowed = tuple(allowed)
        if not message:
            message = f"{self.option} must be one of {', '.join(map(repr, self.allowed))} (got {value!r})"
        self.message = message
        super().__init__(message)

    def __reduce__(self):
        return (type(self), (self.option, self.value, self.allowed, self.message))


class ConversionError(BaardaError, ValueError):
    """A model that the target format cannot hold: ``item`` names the camera or point (or the
    model's convention) at fault and ``reason`` says what the format lacks."""

    def __init__(self, item: str, reason: str, message: str = ""):
        self.item = str(item)
        self.reason = reason
        self.message = message or f"{self.item}: {reason}"
        super().__init__(self.message)

    def __reduce__(self):
        return (type(self), (self.item, self.reason, self.message))


class HypothesisError(BaardaError, ValueError):
    """A hypothesis H that the test cannot use as asked: ``rows`` is H's number of rows and
    ``n`` the adjustment's number of observations when they differ; ``q`` the dimension the
    test sees (0: the test sees no error of this hypothesis) when a lower bound is asked for."""

    def __init__(self, message: str, rows: int | None = None, n: int | None = None, q: int | None = None):
        self.rows, self.n, self.q = rows, n, q
        self.message = message
        super().__init__(message)

    def __reduce__(self):
        return (type(self), (self.message, self.rows, self.n, self.q))


class CovarianceError(BaardaError, ValueError):
    """The covariance clusters do not fit the observations: ``cluster`` is the cluster at fault
    (None when the fault is not one cluster's) and ``observations`` the indices of observations
    that no cluster covers (at most ten), if that is the fault."""

    def __init__(self, message: str, cluster: int | None = None, observations=()):
        self.cluster = cluster
        self.observations = tuple(int(i) for i in observations)
        self.message = message
        super().__init__(message)

    def __reduce__(self):
        return (type(self), (self.message, self.cluster, self.observations))


class NotFoundError(BaardaError, KeyError):
    """What a hypothesis names is not in the model: ``what`` says the kind of item (``"image
    point"``, ``"control point"``, ``"model point"``, ``"AP group"``) and ``ids`` its ids. A
    :class:`KeyError` too; ``str(err)`` is the message without KeyError's quotes."""

    def __init__(self, what: str, ids: dict, message: str = ""):
        self.what = str(what)
        self.ids = dict(ids)
        self.message = message or f"no {self.what} " + ", ".join(f"{k} {v}" for k, v in self.ids.items())
        super().__init__(self.message)

    def __str__(self):
        return self.message

    def __reduce__(self):
        return (type(self), (self.what, self.ids, self.message))


class UsageError(BaardaError, ValueError):
    """A request the command line or a caller made that cannot be met as asked (an option value:
    ``--sbase`` naming an unknown point, ``--risk`` without a tolerance, a malformed
    ``--exchange``): the caller's mistake, not the file's. ``str(err)`` starts with the option."""
