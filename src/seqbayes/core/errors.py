"""The samplers' exceptions and warnings, and where the package documents them."""

__all__ = ["ZeroLikelihoodError", "TemperingLimitError", "PriorDataConflictWarning",
           "InnerFilterWarning", "zero_likelihood_message", "prior_name", "documented"]


def prior_name(step: int) -> str:
    """What the particles of ``step`` were drawn from, for error messages."""
    return "prior" if step == 1 else "predictive distribution"


def zero_likelihood_message(step: int, prior: str, likelihood) -> str:
    """Why no sample of ``step`` has a non-zero likelihood: the model returned NaN for every one (a failed
    solve: the model's fault, not the prior's) or the ``prior`` is too far from the data.

    ``likelihood``: the step's :class:`~seqbayes.core.likelihood.ValidatedLikelihood` (its counts).
    """
    if 0 < likelihood.n_evals <= likelihood.n_nan:
        return (f"step {step}: the likelihood returned NaN for every sample ({likelihood.n_nan} evaluations): the "
                f"model failed at all of them (a solver that did not converge, a division by zero, ...); "
                f"check the model at these parameters (NaN is read as zero likelihood)")
    return f"step {step}: every sample has zero likelihood; the {prior} is too far from the data"


def documented(page: str) -> str:
    """Where ``page`` (a page of the documentation, e.g. ``"prior_data_conflict"``) is explained, for a
    message: the short text that ships with the package (``seqbayes/data/WARNINGS.md``) and the page at
    the documentation address the package declares, if it declares one."""
    from importlib import metadata

    try:
        urls = metadata.metadata("seqbayes").get_all("Project-URL") or []
    except metadata.PackageNotFoundError:  # run from a source tree without installing
        urls = []
    base = next((u.split(",", 1)[1].strip() for u in urls if u.split(",", 1)[0].strip() == "Documentation"), None)
    online = f", and the page {page} at {base.rstrip('/')}/{page}/" if base else f" and docs/{page}.md in the sources"
    return f"see seqbayes/data/WARNINGS.md in the installed package{online}"


class ZeroLikelihoodError(RuntimeError):
    """Every sample has zero likelihood for a dataset."""


class PriorDataConflictWarning(RuntimeWarning):
    """A step's posterior lies far in the tail of its prior (``StepInfo.prior_data_conflict``)."""


class InnerFilterWarning(RuntimeWarning):
    """SMC^2's inner particle filters are degenerate (``StepInfo.inner_ess`` below 0.05)."""


class TemperingLimitError(RuntimeError):
    """Bridging to a dataset took more tempering stages than allowed (``max_stages``)."""
