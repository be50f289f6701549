"""The study's data plan: how one health state's samples are shared out (section 6.3, Figure 6.6).

Per health state the study records 250,000 samples at 200 Hz and splits them, in time order, into

1. **reference** - 10,000 samples for the healthy reference model (NARX or Box-Jenkins). Only the
   healthy state's part trains the reference model; the other states keep the same layout so that
   every state's later parts start at the same offset (their reference part is simply not used);
2. **base** - 40,000 samples whose prediction errors give the base prediction-error distribution of
   the state (one per sensor);
3. **classifier** - 200 windows of 1,000 samples (5 s) each, 200,000 samples, whose relative
   entropies against every base distribution are the classifier's inputs.

The parts never overlap, so the classifier never sees samples its base distributions were fitted
on. Classifier windows are ``window`` samples long and start every ``hop`` samples; with
``hop < window`` consecutive windows overlap and fewer samples are needed
(``window + (classifier_windows - 1) * hop``), with ``hop > window`` samples between windows are
skipped.
"""

from __future__ import annotations

from dataclasses import dataclass

from hydrowatch.errors import DataError, ParameterError


@dataclass(frozen=True)
class DataPlan:
    """How many samples of each health state go to each part (study section 6.3).

    Parameters
    ----------
    reference_samples : int, default 10_000
        Samples for the reference model (used from the healthy state only), 50 s at 200 Hz.
    base_samples : int, default 40_000
        Samples for the base prediction-error distributions, 200 s at 200 Hz.
    classifier_windows : int, default 200
        Windows per state for the classifier (train, validation and test together).
    window : int, default 1000
        Samples per window, 5 s at 200 Hz.
    hop : int, default 1000
        Samples between the starts of consecutive windows (``window``: no overlap).
    """

    reference_samples: int = 10_000
    base_samples: int = 40_000
    classifier_windows: int = 200
    window: int = 1000
    hop: int = 1000

    def __post_init__(self) -> None:
        for name in ("reference_samples", "base_samples", "classifier_windows", "window", "hop"):
            value = getattr(self, name)
            minimum = 0 if name == "reference_samples" else 1
            if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
                raise ParameterError(
                    f"DataPlan.{name} must be an integer >= {minimum}. Got {value!r}. Pass a whole number of samples."
                )
        if self.base_samples < 2:
            raise ParameterError(
                f"DataPlan.base_samples must be >= 2 to fit a distribution. Got {self.base_samples}."
            )

    @property
    def classifier_samples(self) -> int:
        """Samples the classifier windows span: ``window + (classifier_windows - 1) * hop``."""
        return self.window + (self.classifier_windows - 1) * self.hop

    @property
    def samples_per_state(self) -> int:
        """Samples one health state needs: 250,000 with the study's defaults."""
        return self.reference_samples + self.base_samples + self.classifier_samples


@dataclass(frozen=True)
class StateSplit:
    """Sample ranges of one state's recording, as slices into its sample axis."""

    reference: slice
    base: slice
    classifier: slice


def split_state(n_samples: int, plan: DataPlan | None = None) -> StateSplit:
    """Share out one health state's ``n_samples`` samples according to ``plan``.

    Parameters
    ----------
    n_samples : int
        Samples available for the state (200 Hz).
    plan : DataPlan, optional
        Defaults to the study's plan (``DataPlan()``).

    Returns
    -------
    StateSplit
        ``reference`` = ``[0, reference_samples)``, ``base`` = the next ``base_samples``,
        ``classifier`` = the next ``classifier_samples``. Samples beyond the plan are left out.

    Raises
    ------
    DataError
        When ``n_samples`` is smaller than ``plan.samples_per_state``.
    """
    plan = DataPlan() if plan is None else plan
    if n_samples < plan.samples_per_state:
        raise DataError(
            f"a health state must have at least {plan.samples_per_state} samples for the data plan "
            f"({plan.reference_samples} reference + {plan.base_samples} base + {plan.classifier_windows} "
            f"windows of {plan.window} every {plan.hop}). Got {n_samples}. Record longer or use a smaller DataPlan."
        )
    base_start = plan.reference_samples
    classifier_start = base_start + plan.base_samples
    return StateSplit(
        reference=slice(0, base_start),
        base=slice(base_start, classifier_start),
        classifier=slice(classifier_start, classifier_start + plan.classifier_samples),
    )
