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
