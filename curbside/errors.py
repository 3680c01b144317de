"""Errors that the command-line tools report as one line with exit status 2."""

from __future__ import annotations

from os import PathLike


class CurbsideInputError(Exception):
    """Bad usage or bad input: a file, an argument or data that cannot be used.

    Parameters
    ----------
    source
        The file or argument at fault (``"--bbox"``, a path...).
    problem
        What is wrong with it, in one short sentence.
    """

    def __init__(self, source: str | PathLike[str], problem: str) -> None:
        self.source = str(source)
        self.problem = problem
        super().__init__(f"{self.source}: {problem}")


class CurbsideValueError(CurbsideInputError, ValueError):
    """A :class:`CurbsideInputError` that is also a :class:`ValueError`.

    Raised by APIs that raised a plain ``ValueError`` (or ``TypeError``) for bad input before they named
    the argument at fault (:class:`~curbside.localize.filter.Tracker`), so that both ``except
    ValueError`` and ``except CurbsideInputError`` catch it. :class:`CurbsideInputError` itself is not a
    ``ValueError``: ``except ValueError`` blocks that re-word their own ``CurbsideInputError``
    (``curbside.localize.particle_store``, ``curbside.configio``) would catch it otherwise.
    """
