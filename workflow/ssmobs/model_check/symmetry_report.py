"""The model check's report of the symmetries and the propriety found from the model's terms
(issue 60; :mod:`ssmobs.models.symmetries`, :mod:`ssmobs.models.propriety`): one table of
the symmetries, the propriety findings per prior of the checked cases, and a warning for
each image a user's ``mirror_images`` declares that no found symmetry gives.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..models import StateSpaceModel
from ..models.check_cases import CheckCase, sample_theta
from ..models.log_posterior import neg2_log_posterior
from ..models.propriety import posterior_propriety
from ..models.symmetries import model_symmetries

#: random points at which a declared mirror image is compared with the found maps' images
MIRROR_POINTS = 5


@dataclass
class SymmetryReport:
    """What the check writes under ``symmetries`` and ``propriety``, and its warnings."""

    symmetries: list[dict[str, str]] = field(default_factory=list)
    propriety: list[dict[str, Any]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def lines(self, slug: str) -> list[str]:
        """The printed table: symmetries, then propriety per prior, then warnings."""
        out = [f"symmetries of model '{slug}' (found from its terms; docs/method/symmetries.md):"]
        if not self.symmetries:
            out.append("  none found in the searched families")
        width = max([len(r["kind"]) for r in self.symmetries] + [4])
        out += [f"  {r['kind']:<{width}}  {r['name']}" for r in self.symmetries]
        out.append("propriety of the posterior (flat priors, x0 flat on the line):")
        for row in self.propriety:
            findings = (
                [f"improper: {r}" for r in row["improper"]]
                + [f"edge: {r}" for r in row["edge"]]
                + [f"not determined: {r}" for r in row["undetermined"]]
                + [f"note: {r}" for r in row["notes"]]
            ) or ["nothing found"]
            out.append(f"  prior {row['prior']}:")
            out += [f"    {f}" for f in findings]
        out += [f"warning  {w}" for w in self.warnings]
        return out


def _prior_text(model: StateSpaceModel, case: CheckCase) -> str:
    bounds = model.prior_bounds(case.omega, case.prior)
    return ", ".join(
        f"{n}: ({lo:g}, {hi:g})" for n, lo, hi in zip(model.param_names, bounds.lower, bounds.upper)
    )


def mirror_image_warnings(model: StateSpaceModel, case: CheckCase, T: int, seed: int) -> list[str]:
    """One line per image of ``mirror_images`` that is not the image under a found map at
    random points (a declaration outside the searched families, or a mistake), saying
    whether it leaves -2 log pi unchanged there."""
    if type(model).mirror_images is StateSpaceModel.mirror_images:
        return []
    rng = np.random.default_rng(seed)
    theta, z, _ = sample_theta(model, case, T, MIRROR_POINTS, rng)
    found = model_symmetries(model).images(model, theta)
    (base,) = neg2_log_posterior(model, theta, z)
    out = []
    for i, image in enumerate(model.mirror_images(theta)):
        image = np.asarray(image, dtype=float)
        if any(np.allclose(image, f, rtol=1e-9, atol=1e-9) for f in found):
            continue
        (val,) = neg2_log_posterior(model, image, z)
        same = bool(np.allclose(val, base, rtol=1e-8, atol=1e-8))
        out.append(
            f"mirror_images: declared image {i + 1} is not the image under any symmetry found "
            f"from the terms; it "
            + (
                "leaves -2 log pi unchanged at random points (a map outside the searched "
                "families: used as declared)"
                if same
                else "changes -2 log pi at random points (not a symmetry: check the declaration)"
            )
        )
    return out


def symmetry_report(
    model: StateSpaceModel, cases: Sequence[CheckCase], T: int, seed: int
) -> SymmetryReport:
    """The symmetries, the propriety under each distinct prior of ``cases``, and the warnings
    about ``mirror_images``."""
    found = model_symmetries(model)
    report = SymmetryReport(symmetries=found.table())
    report.warnings += [
        f"{name}: leaves both terms unchanged at random points, but SymPy could not show it: "
        f"not used (declare it in mirror_images if it is a symmetry)"
        if "->" in name
        else name
        for name in found.unconfirmed
    ]
    seen: set[str] = set()
    for case in cases:
        prior = _prior_text(model, case)
        if prior in seen:
            continue
        seen.add(prior)
        answer = posterior_propriety(model, model.prior_bounds(case.omega, case.prior))
        report.propriety.append(
            {
                "prior": prior,
                "improper": list(answer.improper),
                "edge": list(answer.edge),
                "undetermined": list(answer.undetermined),
                "notes": list(answer.notes),
                "label": answer.label(),
            }
        )
    if cases:
        report.warnings += mirror_image_warnings(model, cases[0], T, seed)
    return report
