"""What to train, and the command-line flags that say it (light: imports no model code).

Shared by ``hydrowatch train``, the trainer service and ``hydrowatch demo``.
"""

from __future__ import annotations

import argparse
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from hydrowatch.errors import ParameterError
from hydrowatch.health.plan import DataPlan
from hydrowatch.methods import method_class, method_names
from hydrowatch.rig.plant import PLANT_RIG

DEFAULT_EXPERIMENT = "hydrowatch"
DEFAULT_SCORING_EXPERIMENT = "hydrowatch-scoring"
"""Experiment of ``score --log-run`` runs (apart from the training runs, whose metrics differ)."""
DEFAULT_MODEL_NAME = "hydrowatch"
"""Registered model of the plant's bundles (and, as ``hydrowatch-<rig>``, the start of a rig's: :func:`mlflow_name`)."""
DEFAULT_ALIAS = "champion"
DEFAULT_NARX: dict[str, Any] = {"input_delays": 4, "output_delays": 4, "hidden": 8, "max_iter": 40}
"""Short NARX of the demo (the study's Table 4.5 network is 15/15/35: ``--narx 15,15,35``)."""
DEFAULT_BJ: dict[str, Any] = {"nb": 3, "nf": 3, "nc": 2, "nd": 2, "delay": 0}
"""Box-Jenkins orders of every sensor unless given."""
METHODS = method_names()
"""Health methods (:mod:`hydrowatch.methods`): ``parity`` (component relations, :mod:`hydrowatch.condition`),
``entropy`` (the study's reference models + relative entropies), and any other registered. ``parity`` is the
default: it measures best on a working duty cycle (docs/health-pipeline.md)."""
DEFAULT_METHOD = METHODS[0]
GROUPS = ("both", "all")
"""``--method`` values that train several bundles, one run each (:func:`settings_list_from_args`)."""
DEFAULT_CLI_METHOD = "all"
"""``train``/``trainer`` default: the contract's Box-Jenkins and NARX reference models, and the parity bundle."""
DEMO_PLAN = DataPlan(reference_samples=4000, base_samples=6000, classifier_windows=50, window=1000, hop=500)
"""A small data plan (35,500 samples, 177.5 s per state) that trains in about a minute on 2 cores."""


@dataclass(frozen=True)
class TrainingSettings:
    """What to train.

    Parameters
    ----------
    method : str
        Health method (:data:`METHODS`: ``parity``, ``entropy``, …).
    reference : {"narx", "bj"}
        Kind of the reference models (``entropy`` method).
    narx, bj : dict
        Parameters of :class:`~hydrowatch.sysid.NARX` / :class:`~hydrowatch.sysid.BoxJenkins`.
    plan : DataPlan
        How each state's samples are shared out (study section 6.3).
    distribution : {"gaussian", "mixture"}
        Base and window distributions (Eq. 5.3, or mixtures: the study's proposed improvement).
    hidden : int
        Classifier neurons (Table 6.2: 15).
    seed : int
        Seed of the classifier's split and weights.
    """

    method: str = DEFAULT_METHOD
    reference: str = "narx"
    narx: dict[str, Any] = field(default_factory=lambda: dict(DEFAULT_NARX))
    bj: dict[str, Any] = field(default_factory=lambda: dict(DEFAULT_BJ))
    plan: DataPlan = DEMO_PLAN
    distribution: str = "gaussian"
    hidden: int = 15
    seed: int = 0

    @property
    def name(self) -> str:
        """Short name of what is trained: the method's, e.g. ``parity``, or the reference kind (``narx``, ``bj``)
        for ``entropy``."""
        return method_class(self.method).run_name(self)

    def reference_params(self) -> dict[str, Any]:
        """Parameters of the chosen reference model kind."""
        return dict(self.narx if self.reference == "narx" else self.bj)

    def to_dict(self) -> dict[str, Any]:
        """Flat JSON-able form (MLflow parameters, manifest): the method's settings, then the data plan's."""
        if self.method not in METHODS:
            raise ParameterError(f"method must be one of {METHODS}. Got {self.method!r}.")
        out = method_class(self.method).settings_dict(self)
        out.update({f"plan.{k}": v for k, v in asdict(self.plan).items()})
        return out


def mlflow_name(rig: str = PLANT_RIG) -> str:
    """The registered model a rig's bundles go to unless ``--model-name`` says otherwise, which is also the experiment
    of a rig's runs unless ``--experiment`` does: :data:`DEFAULT_MODEL_NAME` (``hydrowatch``) for the plant,
    ``hydrowatch-<rig>`` for any other rig (its description's ``name``), so that training a rig never moves the
    plant's ``hydrowatch@champion`` (issue 17). ``train``, ``trainer``, ``demo`` and the scorer's default ``--model``
    take their names from here."""
    return DEFAULT_MODEL_NAME if rig == PLANT_RIG else f"{DEFAULT_MODEL_NAME}-{rig}"


def default_model_uri(rig: str = PLANT_RIG) -> str:
    """``models:/<mlflow_name(rig)>@champion``: the registry URI a scorer of ``rig`` loads unless given ``--model``."""
    return f"models:/{mlflow_name(rig)}@{DEFAULT_ALIAS}"


def given_or_default_names(experiment: str | None, model_name: str | None, *, register: bool = True,
                           rig: str = PLANT_RIG) -> tuple[str, str | None]:
    """(experiment, registered model or None when not ``register``) of ``rig``'s training: each name given wins, else
    :data:`DEFAULT_EXPERIMENT` for the plant's experiment and :func:`mlflow_name` for the rest."""
    experiment = experiment or (DEFAULT_EXPERIMENT if rig == PLANT_RIG else mlflow_name(rig))
    return experiment, (model_name or mlflow_name(rig)) if register else None


def tracking_names(args: argparse.Namespace, rig: str = PLANT_RIG) -> tuple[str, str | None]:
    """:func:`given_or_default_names` of :func:`add_tracking_arguments`' flags (``--experiment``, ``--model-name``,
    ``--no-register``) for ``rig``."""
    return given_or_default_names(args.experiment, args.model_name, register=not args.no_register, rig=rig)


STUDY_PLAN = DataPlan()
"""The study's full plan: 10,000 reference, 40,000 base samples, 200 windows of 1,000 (1250 s per state)."""


def _ints(text: str, names: tuple[str, ...], flag: str) -> dict[str, int]:
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != len(names):
        raise ParameterError(f"{flag} must be {len(names)} comma-separated integers {','.join(names).upper()}. "
                             f"Got {text!r}.")
    return dict(zip(names, values))


def add_training_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags that choose what is trained (shared by ``train``, ``trainer`` and ``demo``)."""
    g = parser.add_argument_group("training")
    g.add_argument("--method", choices=(*METHODS, *GROUPS), default=DEFAULT_CLI_METHOD,
                   help=f"health method: {DEFAULT_METHOD} (component relations, the verdicts hydrowatch "
                        "recommends), entropy (the study's reference models + relative entropies, with --reference), "
                        f"{''.join(f'{m}, ' for m in METHODS[2:])}"
                        "both (entropy, then parity), all (default: entropy with Box-Jenkins, entropy with NARX, "
                        "then parity; three runs to compare in MLflow)")
    g.add_argument("--reference", choices=("narx", "bj"), default="narx",
                   help="reference model kind of the entropy method (default narx)")
    g.add_argument("--narx", default=None, metavar="NU,NY,H",
                   help=f"NARX input delays, output delays, neurons (default "
                        f"{DEFAULT_NARX['input_delays']},{DEFAULT_NARX['output_delays']},{DEFAULT_NARX['hidden']}; "
                        "the study: 15,15,35)")
    g.add_argument("--narx-iterations", type=int, default=DEFAULT_NARX["max_iter"],
                   help=f"Levenberg-Marquardt iterations at most (default {DEFAULT_NARX['max_iter']})")
    g.add_argument("--bj", default=None, metavar="NB,NF,NC,ND",
                   help="Box-Jenkins orders (default {nb},{nf},{nc},{nd})".format(**DEFAULT_BJ))
    g.add_argument("--bj-delay", type=int, default=DEFAULT_BJ["delay"], help="Box-Jenkins dead time, samples")
    g.add_argument("--full-plan", action="store_true",
                   help="the study's data plan (1250 s per state) instead of the small default (177.5 s)")
    g.add_argument("--windows", type=int, default=None, help="classifier windows per state (plan)")
    g.add_argument("--distribution", choices=("gaussian", "mixture"), default="gaussian",
                   help="base and window distributions (default gaussian, Eq. 5.3)")
    g.add_argument("--seed", type=int, default=0, help="classifier seed (default 0)")


def settings_from_args(args: argparse.Namespace) -> TrainingSettings:
    """:class:`TrainingSettings` from :func:`add_training_arguments`' flags (``--method both``: the default method)."""
    narx = dict(DEFAULT_NARX)
    if args.narx:
        narx.update(_ints(args.narx, ("input_delays", "output_delays", "hidden"), "--narx"))
    narx["max_iter"] = args.narx_iterations
    bj = dict(DEFAULT_BJ)
    if args.bj:
        bj.update(_ints(args.bj, ("nb", "nf", "nc", "nd"), "--bj"))
    bj["delay"] = args.bj_delay
    plan = STUDY_PLAN if args.full_plan else DEMO_PLAN
    if args.windows is not None:
        plan = replace(plan, classifier_windows=args.windows)
    method = getattr(args, "method", DEFAULT_METHOD)
    method = DEFAULT_METHOD if method in GROUPS else method
    return TrainingSettings(method=method, reference=args.reference, narx=narx, bj=bj, plan=plan,
                            distribution=args.distribution, seed=args.seed)


def settings_list_from_args(args: argparse.Namespace) -> list[TrainingSettings]:
    """One :class:`TrainingSettings` per bundle ``--method`` names.

    ``both``: entropy (``--reference``), then parity; ``all``: entropy with Box-Jenkins, entropy with
    NARX, then parity. The default method comes last, so a registry alias ends on it.
    """
    base = settings_from_args(args)
    if args.method == "both":
        return [replace(base, method="entropy"), replace(base, method=DEFAULT_METHOD)]
    if args.method == "all":
        return [replace(base, method="entropy", reference="bj"), replace(base, method="entropy", reference="narx"),
                replace(base, method=DEFAULT_METHOD)]
    return [base]


def add_tracking_arguments(parser: argparse.ArgumentParser) -> None:
    """``--tracking-uri``, ``--experiment``, ``--model-name``, ``--alias``, ``--no-register``."""
    g = parser.add_argument_group("MLflow")
    g.add_argument("--tracking-uri", default=None,
                   help="MLflow tracking URI (default $MLFLOW_TRACKING_URI or sqlite:///<cwd>/mlruns/mlflow.db)")
    g.add_argument("--experiment", default=None,
                   help=f"experiment (default {DEFAULT_EXPERIMENT}; with --rig {mlflow_name('<rig>')}, the rig's name)")
    g.add_argument("--model-name", default=None,
                   help=f"registered model (default {DEFAULT_MODEL_NAME}; with --rig {mlflow_name('<rig>')}, so that a "
                        f"rig's model never takes the plant's {default_model_uri()})")
    g.add_argument("--alias", default=DEFAULT_ALIAS, help=f"alias moved to the new version (default {DEFAULT_ALIAS})")
    g.add_argument("--no-register", action="store_true", help="log the run but do not register the bundle")
    g.add_argument("--check-seconds", type=float, default=0.0, metavar="S",
                   help="after training, measure accuracy on simulated recordings of S s per state (another seed: "
                        "training command, duty cycle, narrow range) and log it as metrics (default 0: skip)")


