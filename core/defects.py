"""Local defects: parts of a network or block that the observations do not determine.

A *local* defect is not the datum defect of the whole block (translations, rotations, scale,
diagnosed by :mod:`baarda.datum`), but a point, an image or a coordinate component that the
observations leave undetermined on their own: a point seen from two images with zero baseline,
a point on a single ray, a traverse point without any height information. baarda names each of
them, leaves it out of the adjustment (or adjusts the components that are determined, as
gama-local does for heights) and analyses the rest; ``baarda analyze --strict`` makes them an
error instead.
"""

from __future__ import annotations

from dataclasses import dataclass

from .adjust import adjust
from .errors import DatumDefectError


@dataclass(frozen=True)
class LocalDefect:
    """One undetermined entity.

    entity: ``"point"``, ``"image"``, ``"camera"`` ... ; id: the entity's id as in the file;
    components: what is undetermined (``("x", "y", "z")`` for a whole point, ``("z",)`` for a
    height); reason: why, in words (``"zero baseline: images 3, 4 have the same centre"``);
    action: what baarda did (``"left out"``, ``"adjusted in x, y"``).
    """

    entity: str
    id: str
    components: tuple[str, ...]
    reason: str
    action: str = "left out"

    def as_dict(self) -> dict:
        return {"entity": self.entity, "id": self.id, "components": list(self.components),
                "reason": self.reason, "action": self.action}

    def text(self) -> str:
        comps = ", ".join(self.components)
        return f"{self.entity} {self.id} ({comps}): {self.reason} — {self.action}"


def adjust_setting_aside(problem, options, progress, rounds: int, set_aside):
    """The safety net around :func:`baarda.adjust.adjust`: ``(adjustment, problem adjusted)``.

    When the adjustment finds the normal equations singular (:class:`~baarda.errors.DatumDefectError`),
    ``set_aside(problem, err, first)`` returns the problem without the local defects ``err``
    names (``first`` is the first such error), or raises when the defect is not local; the
    problem is adjusted again, at most ``rounds`` more times, then ``first`` is raised.
    """
    first = None
    for _ in range(rounds + 1):
        try:
            return adjust(problem, options, progress=progress), problem
        except DatumDefectError as err:
            first = first or err
            problem = set_aside(problem, err, first)
    raise first
