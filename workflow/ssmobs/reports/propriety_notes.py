"""What a table says about a scenario's posterior before it shows a Stan number.

With flat priors (Sec. IV) the posterior of a scenario can be improper: an infinite-order
symmetry moves a flat-prior variable without bound, or x0 drops out of the likelihood at
parameter values inside the prior box (docs/method/improper-posteriors.md).  NUTS still
runs there, but |K^Stan|, the marginal MAPs (Eq. (11)), the intervals (Eq. (12)), their
coverage, bias and MSE then describe no distribution, so the tables write the reason
(:meth:`Propriety.label`, "improper: <reason>") instead of those numbers.  The same
drop-out at an end of the prior support (the paper's documented cases, e.g. Same's a -> 0
with the prior (0, 1)) is an ``edge`` finding: the numbers stay and the note is shown.

The analysis itself is :func:`ssmobs.models.propriety.posterior_propriety`; this module
only turns its answer into the words a table shows.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from ..config.scenario import Scenario
    from ..models.base import PriorBounds, StateSpaceModel

#: the words a table shows in place of a Stan number of an improper posterior
NOT_SHOWN_IMPROPER = "not shown: improper"


class ProprietyAnswer(Protocol):
    """What :func:`ssmobs.models.propriety.posterior_propriety` returns (its ``Propriety``;
    an ``undetermined`` tuple, what the analysis could not decide, is read where present)."""

    @property
    def improper(self) -> tuple[str, ...]: ...

    @property
    def edge(self) -> tuple[str, ...]: ...

    @property
    def is_improper(self) -> bool: ...

    def label(self) -> str: ...


#: (model, prior bounds) -> the posterior's propriety
ProprietyAnalysis = Callable[["StateSpaceModel", "PriorBounds"], ProprietyAnswer]


def propriety_analysis() -> ProprietyAnalysis:
    """The project's analysis of a posterior's propriety (from the model's terms)."""
    from ..models.propriety import posterior_propriety

    return posterior_propriety


@dataclass(frozen=True)
class PosteriorNote:
    """A scenario's propriety in a table's words: ``improper`` is "" or "improper: <reason>;
    ..." (:meth:`Propriety.label`), ``edge`` the documented end-of-support findings ("" if
    none), joined by "; "."""

    improper: str
    edge: str

    @property
    def is_improper(self) -> bool:
        return bool(self.improper)


def posterior_note(scenario: Scenario, analysis: ProprietyAnalysis | None = None) -> PosteriorNote:
    """The propriety of ``scenario``'s posterior under its prior (``analysis`` defaults to
    :func:`propriety_analysis`).  What the analysis could not decide makes the posterior one
    that may be improper: its numbers are not shown either, and the words say so."""
    analysis = analysis or propriety_analysis()
    model = scenario.model
    answer = analysis(model, model.prior_bounds(scenario.omega, scenario.prior))
    reasons = [answer.label()] if answer.is_improper else []
    undecided: tuple[str, ...] = getattr(answer, "undetermined", ())
    if undecided:
        reasons.append("may be improper (not decided): " + "; ".join(undecided))
    return PosteriorNote(improper="; ".join(reasons), edge="; ".join(answer.edge))


def config_note(
    config: Mapping[str, Any], analysis: ProprietyAnalysis | None = None
) -> PosteriorNote:
    """:func:`posterior_note` of a scenario given as its config entry."""
    from ..config.scenario import Scenario

    return posterior_note(Scenario.from_config(dict(config)), analysis)


def add_note_columns(rows: list[dict[str, Any]], notes: list[PosteriorNote]) -> None:
    """Give every row the columns ``improper`` and ``edge`` where some row has a finding
    (a table of proper scenarios without edge findings keeps its columns)."""
    for column in ("improper", "edge"):
        if any(getattr(n, column) for n in notes):
            for row, note in zip(rows, notes, strict=True):
                row[column] = getattr(note, column)
