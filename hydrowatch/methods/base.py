"""What every health method provides (:class:`HealthMethod`), and what its parts hand each other.

A method is one package under ``hydrowatch/methods/`` exposing one class, registered by name in
:mod:`hydrowatch.methods`. The class fits itself from recordings grouped by health state
(:meth:`HealthMethod.fit`, a classmethod returning a :class:`MethodFit`); an instance is a fitted
method that a :class:`~hydrowatch.training.bundle.ModelBundle` holds, saves into the bundle folder
and loads back, scores a whole recording (:meth:`HealthMethod.score`) and gives the online fleet
driver (:class:`~hydrowatch.training.online.OnlineScorer`) its streaming part, one of

* a :class:`WindowJudge`: the method reads raw windows of its channels, the driver cuts them (every
  machine a row of one fleet-wide array) and hands over closed windows in batches;
* a :class:`StreamEngine`: a judge whose windows hold values the method computes from each machine's
  samples with a state of its own (delay lines of reference models, warm-up).

Chunk hygiene (gaps, NaN, late chunks), breaks, staggering, batching and the verdicts' times are the
driver's (:class:`~hydrowatch.training.window_fleet.WindowFleet`), the same for every method.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, Self, runtime_checkable

import numpy as np

from hydrowatch.errors import DataError, ParameterError
from hydrowatch.expected import ExpectedWindow
from hydrowatch.log import event, get_logger
from hydrowatch.recording import INPUT, SENSORS, Recording
from hydrowatch.verdict import Verdict

if TYPE_CHECKING:
    from hydrowatch.training.options import TrainingSettings

HEALTHY = "healthy"
"""The state every training set must include (it trains the reference models and the commissionings)."""
_log = get_logger(__name__)


def ordered_states(states: Sequence[str]) -> list[str]:
    """``healthy`` first, then the other states in the order given."""
    return [HEALTHY, *[s for s in states if s != HEALTHY]]


def shared_sensors(grouped: Mapping[str, list[Recording]]) -> list[str]:
    """The sensors every training recording has, in :data:`~hydrowatch.recording.SENSORS` order: what a method
    trains on and records (a recording may carry any subset of the sensors, :mod:`hydrowatch.channels`).

    Raises
    ------
    DataError
        When the recordings share no sensor (naming what each kind of recording has).
    """
    runs = [r for group in grouped.values() for r in group]
    shared = [s for s in SENSORS if all(s in r.channels for r in runs)]
    if not shared:
        kinds = sorted({tuple(s for s in SENSORS if s in r.channels) for r in runs})
        raise DataError(f"training recordings must share at least one sensor of {list(SENSORS)}. Got recordings "
                        f"with {[list(k) for k in kinds]}; train on recordings of one set of sensors.")
    dropped = sorted({s for r in runs for s in SENSORS if s in r.channels} - set(shared))
    if dropped:
        event(_log, "sensors not in every training recording left out", sensors=",".join(dropped))
    return shared


def check_channels(method: HealthMethod, recording: Recording) -> None:
    """Refuse a recording that lacks a channel the fitted ``method`` reads (the command and its sensors).

    Raises
    ------
    DataError
        Naming the missing channels, the method's channels and the recording's.
    """
    missing = [c for c in method.channels if c not in recording.channels]
    if missing:
        raise DataError(f"recording must have the channel(s) {missing}: this {method.name} model was trained on "
                        f"{method.channels} and reads each of them. Got {sorted(recording.channels)}. Score it with "
                        "a model trained on recordings of the sensors it has.", recording.meta.get("source"))


def data_summary(grouped: Mapping[str, list[Recording]], states: Sequence[str]) -> dict[str, dict[str, Any]]:
    """The manifest's ``data``: per state ``runs``, ``samples`` and the ``sources`` (sorted file names)."""
    return {s: {"runs": len(grouped[s]), "samples": int(sum(len(r) for r in grouped[s])),
                "sources": sorted({str(r.meta.get("source", "")) for r in grouped[s]})} for s in states}


@dataclass
class MethodFit:
    """What :meth:`HealthMethod.fit` returns; the trainer wraps it into a bundle and a ``TrainingResult``.

    Attributes
    ----------
    method : HealthMethod
        The fitted method.
    manifest : dict
        The bundle manifest's method part: ``method``, ``reference`` (None unless the method has reference
        models), ``states``, ``sensors``, ``window``, ``hop``, ``warmup`` (samples), ``settings``, ``data``,
        ``metrics`` and whatever the method reads back in :meth:`HealthMethod.load`.
    window_scores : dict of str to ndarray, shape (m_k, n_rows, n_states)
        The ``kl`` scores of each state's evaluation windows (the report's table).
    evaluation : dict
        ``test_accuracy``, ``test_accuracy_with_open_set``, ``known_rejected``, ``per_class_recall``, ``labels``,
        ``confusion_matrix`` (true rows), ``test_windows``, ``ece``.
    base_errors : dict of str to ndarray, shape (n_k, n_sensors)
        Prediction errors of each state's base part (entropy method; else empty).
    reference : dict
        Per sensor, the reference model's figures (entropy method; else empty).
    """

    method: HealthMethod
    manifest: dict[str, Any]
    window_scores: dict[str, np.ndarray]
    evaluation: dict[str, Any]
    base_errors: dict[str, np.ndarray] = field(default_factory=dict)
    reference: dict[str, Any] = field(default_factory=dict)


@dataclass
class OfflineScores:
    """A recording scored window by window (:meth:`HealthMethod.score`).

    Attributes
    ----------
    starts : ndarray of int, shape (n_windows,)
        First sample of each window, counted after the method's warm-up.
    verdicts : list of Verdict
    scores : ndarray, shape (n_windows, n_rows, n_states)
        The ``kl`` scores (rows :attr:`HealthMethod.kl_rows`).
    degradation : optional
        A :class:`~hydrowatch.condition.degradation.Degradation` when the method estimates one (parity).
    """

    starts: np.ndarray
    verdicts: list[Verdict]
    scores: np.ndarray
    degradation: Any = None


Judged = tuple[Verdict, np.ndarray] | tuple[Verdict, np.ndarray, dict[str, Any] | None]
"""What a :class:`WindowJudge` gives per window: verdict, ``kl`` scores and, optionally, the degradation index."""


@runtime_checkable
class WindowJudge(Protocol):
    """Streaming part of a method that reads raw windows: the driver cuts them, this judges them.

    ``columns`` (command first) and ``defaults`` (column → value assumed when a chunk lacks it) say what
    the driver reads; ``window`` and ``hop`` are in samples.
    """

    columns: list[str]
    defaults: dict[str, float]
    window: int
    hop: int

    def judge(self, raw: np.ndarray, machines: Sequence[str]) -> Sequence[Judged]:
        """Verdicts and ``kl`` scores (n_rows, n_states) of closed windows ``raw`` (m, window, n_columns) of
        ``machines`` (m, in closing order; a method that pools keeps each machine's recent evidence); a method with a
        degradation index adds it as a third item (``{fault: {"value", "ci95"}}`` or None)."""
        ...


@runtime_checkable
class StreamEngine(WindowJudge, Protocol):
    """A :class:`WindowJudge` whose windows hold values computed per machine with a state of its own (the entropy
    method's prediction errors): the driver turns every clean segment into values first, and starts the windows at
    the first sample where every value is finite (the warm-up), again after each break.

    ``width`` is the number of values per sample; ``staggers`` whether the driver may stagger the windows.
    """

    width: int
    staggers: bool

    def new_states(self) -> Any:
        """A machine's fresh state (after a break: warm-up again)."""
        ...

    def values(self, x: np.ndarray, states: Sequence[Any]) -> np.ndarray:
        """Values (M, n, width) of M machines' segments x (M, n, n_columns), NaN while warming up; updates
        ``states``."""
        ...


@runtime_checkable
class ExpectsSensors(Protocol):
    """A streaming part (:class:`WindowJudge` or :class:`StreamEngine`) that can also say what its model expected a
    closed window's sensors to read (the parity relations' outputs, the reference models' one-step predictions):
    the fleet driver calls :meth:`expect` once, before it reads ``width``, and then asks it for the windows it judged
    (when the scorer publishes ``…/expected``)."""

    def expect(self) -> None:
        """Get ready to be asked :meth:`expected` (a stream engine then keeps each sensor's measured samples beside
        its values in the windows: its ``width`` grows); without this call a window holds only what judging needs."""
        ...

    def expected(self, raw: np.ndarray, machines: Sequence[str]) -> Sequence[ExpectedWindow | None]:
        """Per closed window ``raw`` (m, window, width) of ``machines``, measured and expected points of each sensor
        the model predicts (:class:`hydrowatch.expected.ExpectedSensor`), or None for a window it cannot judge."""
        ...


class HealthMethod:
    """A fitted health method (module docstring): the base class every method subclasses. Sizes in samples.

    A subclass sets the class attributes, implements :meth:`fit`, :meth:`load`, :meth:`save`,
    :meth:`score`, :meth:`online` and the properties :attr:`sensors`, :attr:`states`, :attr:`window`,
    :attr:`hop`; the rest has defaults for a method that reads the command and its sensors, judges
    each window alone and cannot be commissioned.

    Attributes
    ----------
    name : str
        Registered name (``--method NAME``, the manifest's ``method``).
    pools : bool
        Whether a verdict may pool a machine's recent windows (``smoothing`` > 1).
    default_smoothing : int
        Windows each verdict pools unless told (1: each window alone).
    commissionable : bool
        Whether :meth:`commission` adapts the method to one machine.
    row_label : str
        What the ``kl`` rows are (``sensor``, ``relation``).
    streams : str
        The bus topic the scorer service judges with this method: ``sensors`` (samples, :meth:`online`) or
        ``cycles`` (a rig's whole cycles, the ``cycles`` method; docs/rigs.md).
    """

    name: ClassVar[str]
    pools: ClassVar[bool] = False
    default_smoothing: ClassVar[int] = 1
    commissionable: ClassVar[bool] = False
    row_label: ClassVar[str] = "sensor"
    streams: ClassVar[str] = "sensors"

    @classmethod
    def fit(cls, grouped: Mapping[str, list[Recording]], settings: TrainingSettings) -> MethodFit:
        """Fit from recordings grouped by state (``healthy`` among them)."""
        raise NotImplementedError

    @classmethod
    def settings_dict(cls, settings: TrainingSettings) -> dict[str, Any]:
        """The settings this method uses, flat (MLflow parameters, the manifest), ``method`` first; the data
        plan's are added by :meth:`TrainingSettings.to_dict`."""
        return {"method": cls.name}

    @classmethod
    def run_name(cls, settings: TrainingSettings) -> str:
        """Short name of what ``settings`` train (MLflow run names, ``--method all`` folders)."""
        return cls.name

    @classmethod
    def load(cls, directory: Path, manifest: Mapping[str, Any]) -> Self:
        """Read what :meth:`save` wrote into the bundle folder ``directory``."""
        raise NotImplementedError

    def save(self, directory: Path) -> list[Path]:
        """Write the fitted parts under the bundle folder; returns the files (the bundle hashes them)."""
        raise NotImplementedError

    @property
    def headline(self) -> str:
        """How the report introduces a run."""
        return f"{self.name} method"

    @property
    def table_caption(self) -> str:
        """Caption of the report's table of median ``kl`` scores per state (rows :attr:`kl_rows`)."""
        return f"Median score of each state's test windows per {self.row_label} and trained state:"

    @property
    def sensors(self) -> list[str]:
        """Sensors read, in the order of their columns."""
        raise NotImplementedError

    @property
    def channels(self) -> list[str]:
        """Every channel read, the command first."""
        return [INPUT, *self.sensors]

    @property
    def states(self) -> list[str]:
        """Trained states, in the decision's order."""
        raise NotImplementedError

    @property
    def kl_rows(self) -> list[str]:
        """Rows of a window's ``kl`` scores."""
        return self.sensors

    @property
    def window(self) -> int:
        """Samples per window."""
        raise NotImplementedError

    @property
    def hop(self) -> int:
        """Samples between window starts."""
        raise NotImplementedError

    @property
    def warmup(self) -> int:
        """Samples before the first window can start."""
        return 0

    def score(self, recording: Recording, smoothing: int = 1) -> OfflineScores:
        """Every window of a recording (after the warm-up), judged; ``smoothing`` > 1 only if :attr:`pools`."""
        raise NotImplementedError

    def online(self, *, smoothing: int = 1,
               unit_method: Callable[[str], HealthMethod | None] | None = None) -> WindowJudge:
        """The streaming part for the fleet driver (a :class:`StreamEngine` when values need a state per machine);
        ``unit_method``: machine → its commissioned method, or None for this one."""
        raise NotImplementedError

    def commission(self, recordings: list[Recording]) -> tuple[Self, dict[str, Any]]:
        """This method adapted to one machine from its healthy recordings, and a summary of the adaptation."""
        from hydrowatch.condition.commission import CommissioningError

        raise CommissioningError(f"commissioning adapts parity bundles (train --method parity, the default). Got an "
                                 f"{self.name} bundle; train it on this unit instead.")


def refuse_smoothing(name: str, smoothing: int) -> None:
    """Raise for a method that judges each window alone and is asked to pool ``smoothing`` != 1 windows."""
    raise ParameterError(f"smoothing must be 1 for an {name} bundle. Got {smoothing!r}; pooling windows is the "
                         "parity method's (train with --method parity).")
