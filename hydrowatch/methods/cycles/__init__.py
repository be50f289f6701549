"""Per-cycle verdicts per component of any rig (docs/rigs.md, issue 17): the ``cycles`` method.

Trained from a rig description's imported cycles (``hydrowatch train --rig NAME|FILE --data PATH``,
:func:`hydrowatch.io.rig_cycles.read_rig_data`), not from labelled recordings: every component the description
labels (``[labels.<component>]``, flags excluded) gets its own open-set classifier
(:mod:`hydrowatch.methods.cycles.train`), so each cycle has one verdict per component with that component's states,
probabilities and ``unknown`` (:mod:`hydrowatch.cycles.openset`). Bundle folder: ``cycles/rig.toml`` (the
description it was trained with, which reads the data it scores) and ``cycles/model.json`` (the fitted
classifiers' parameters and arrays, no pickle; :mod:`hydrowatch.cycles.state`).

:meth:`CyclesMethod.judge_cycles` judges cycles: ``hydrowatch score`` of a rig's data, and the scorer service of
``rig_cycles`` messages (:attr:`CyclesMethod.streams` is ``cycles``, :mod:`hydrowatch.training.cycle_stream`).
:meth:`CyclesMethod.online` (sensor samples) refuses, and so does :meth:`CyclesMethod.score` of a plant recording.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from hydrowatch.cycles.openset import UNKNOWN, OpenSetComponent
from hydrowatch.cycles.state import from_json_tree, to_json_tree
from hydrowatch.errors import DataError, ParameterError
from hydrowatch.methods.base import HealthMethod, MethodFit, OfflineScores, WindowJudge
from hydrowatch.methods.cycles.train import (
    component_data,
    component_states,
    evaluate_component,
    fit_component,
    state_name,
)
from hydrowatch.recording import Recording
from hydrowatch.rig import RigDescription
from hydrowatch.rig.description import rig_from_text
from hydrowatch.verdict import Verdict

if TYPE_CHECKING:
    from hydrowatch.io.wide import Cycles
    from hydrowatch.training.options import TrainingSettings

RIG_FILE, MODEL_FILE = "rig.toml", "model.json"
LEGACY_MODEL_FILE = "model.pkl"
"""The pickle of scikit-learn objects bundles held before 2026-11-26: refused on loading."""
FORMAT = 3
"""Format of ``model.json`` written: per component the open-set classifier's parameters and arrays
(:mod:`hydrowatch.cycles.state`). 2 (2026-11-26): the transients' step shares and reduced-rank decision
(``normalised``, ``discriminants``, ``steps_``, ``typical_steps_``, ``priors_``), which a reader of format 1 does not
know; 3 (2026-11-26, branch rig17b): the trees' vote (``trees``, ``tree_weight``, ``coverage``, ``vote_``), which a
reader of format 2 would ignore, deciding otherwise than the model was trained to. 1 and 2 are still read (without
the vote, as trained)."""
READ_FORMATS = (1, 2, 3)


class CyclesMethod(HealthMethod):
    """Fitted per-component classifiers of a rig's cycles (module docstring).

    Parameters
    ----------
    rig_text : str
        The rig description's TOML text.
    models : dict of str to OpenSetComponent
        Per component, its fitted classifier.
    features : dict of str to str
        Per component, the feature set chosen (``statistics``, ``transients`` or ``entropy``).
    """

    name: ClassVar[str] = "cycles"
    row_label: ClassVar[str] = "component"
    streams: ClassVar[str] = "cycles"

    def __init__(self, rig_text: str, models: dict[str, OpenSetComponent], features: dict[str, str],
                 source: str = RIG_FILE) -> None:
        self.rig_text, self.models, self.features = rig_text, models, features
        self.rig: RigDescription = rig_from_text(rig_text, source)
        self.component_states = {c: component_states(self.rig.label(c)) for c in models}

    @classmethod
    def fit(cls, grouped: Mapping[str, list[Recording]], settings: TrainingSettings) -> MethodFit:
        """Refused: this method is trained from a rig's cycles (:meth:`fit_cycles`)."""
        raise DataError("the cycles method trains from a rig's cycles, not from labelled recordings. Train it with "
                        "`hydrowatch train --rig NAME|FILE --data FOLDER --method cycles`.")

    @classmethod
    def fit_cycles(cls, rig_text: str, rig: RigDescription, cycles: Cycles, settings: TrainingSettings) -> MethodFit:
        """Evaluate every component on the honest split, then fit each on all cycles.

        Raises
        ------
        DataError
            When the description labels no component, or the cycles lack a component's labels.
        """
        components = list(rig.components)
        if not components or any(c not in cycles.labels for c in components):
            raise DataError(f"the cycles method needs every cycle's component labels (the description's [labels] "
                            f"file). Got components {components} and labels {sorted(cycles.labels)}.", cycles.source)
        models, features, evaluation = {}, {}, {}
        for c in components:
            data = component_data(rig, cycles.values, cycles.labels, c)
            evaluation[c] = evaluate_component(rig, data, component_states(rig.label(c)))
            models[c], features[c], evaluation[c]["validation_all"] = fit_component(rig, data)
        method = cls(rig_text, models, features)
        accuracy = float(np.mean([evaluation[c]["accuracy"] for c in components]))
        recall = {f"{c}={s}": r for c in components for s, r in evaluation[c]["per_class_recall"].items()}
        summary = {"test_accuracy": accuracy, "test_accuracy_with_open_set": accuracy,
                   "known_rejected": float(np.mean([evaluation[c]["unknown"] for c in components])),
                   "per_class_recall": recall, "labels": method.states, "components": evaluation,
                   "test_windows": int(sum(evaluation[c]["test_cycles"] for c in components)),
                   "split": "honest: per component, each class's first 70 % of cycles train, the last 30 % test"}
        manifest = {"method": cls.name, "reference": None, "states": method.states, "sensors": method.sensors,
                    "window": method.window, "hop": method.hop, "warmup": 0, "settings": settings.to_dict(),
                    "rig": rig.name, "components": method.component_states, "features": features,
                    "data": {"source": cycles.source, "cycles": len(cycles)},
                    "metrics": {"test_accuracy": accuracy, **{f"accuracy.{c}": evaluation[c]["accuracy"]
                                                              for c in components}}}
        return MethodFit(method, manifest, {}, summary)

    @classmethod
    def load(cls, directory: Path, manifest: Mapping[str, Any]) -> CyclesMethod:
        """``cycles/rig.toml`` and ``cycles/model.json`` under ``directory``.

        Raises
        ------
        DataError
            A missing or unreadable file, a ``model.json`` of another format, or a bundle written before
            2026-11-26 whose classifiers are a pickle (``model.pkl``): refused, not unpickled (a pickle can run
            code); train it again with ``train --rig``.
        """
        folder = directory / cls.name
        if not (folder / MODEL_FILE).is_file() and (folder / LEGACY_MODEL_FILE).is_file():
            raise DataError(f"this cycles bundle stores its classifiers as a pickle ({LEGACY_MODEL_FILE}, hydrowatch "
                            f"before 2026-11-26), which is no longer loaded (a pickle can run code). Train it again "
                            f"with `hydrowatch train --rig {manifest.get('rig', 'RIG')} --data DATA --out DIR`.",
                            str(folder))
        try:
            text = (folder / RIG_FILE).read_text(encoding="utf-8")
            stored = json.loads((folder / MODEL_FILE).read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise DataError(f"a cycles bundle must hold {RIG_FILE} and a readable {MODEL_FILE}. Got: {exc}.",
                            str(folder)) from None
        if not isinstance(stored, dict) or stored.get("format") not in READ_FORMATS:
            raise DataError(f"{MODEL_FILE} must be of format {', '.join(map(str, READ_FORMATS[:-1]))} or "
                            f"{READ_FORMATS[-1]}. Got "
                            f"{stored.get('format') if isinstance(stored, dict) else type(stored).__name__}.",
                            str(folder / MODEL_FILE))
        source = str(folder / MODEL_FILE)
        try:
            models = {c: OpenSetComponent.from_state(from_json_tree(tree, source, f"models.{c}"))
                      for c, tree in stored["models"].items()}
        except (KeyError, TypeError) as exc:
            raise DataError(f"{MODEL_FILE} must hold every fitted part of each component's classifier. Got none "
                            f"for {exc}.", source) from None
        return cls(text, models, dict(stored["features"]), str(folder / RIG_FILE))

    def save(self, directory: Path) -> list[Path]:
        """``cycles/rig.toml`` and ``cycles/model.json`` (every component's parameters and arrays, no pickle) under
        ``directory``."""
        folder = directory / self.name
        folder.mkdir(parents=True, exist_ok=True)
        (folder / RIG_FILE).write_text(self.rig_text, encoding="utf-8")
        stored = {"format": FORMAT, "features": self.features,
                  "models": {c: to_json_tree(m.to_state(), f"models.{c}") for c, m in self.models.items()}}
        (folder / MODEL_FILE).write_text(json.dumps(stored, separators=(",", ":")), encoding="utf-8")
        return [folder / RIG_FILE, folder / MODEL_FILE]

    headline = property(lambda self: f"Per-cycle classifiers per component of rig {self.rig.name}")
    sensors = property(lambda self: list(self.rig.channels.names))
    channels = sensors
    kl_rows = property(lambda self: list(self.models))
    window = property(lambda self: int(self.rig.window.samples))
    hop = window

    @property
    def states(self) -> list[str]:
        """Every component's states as ``component=state`` (healthy first within each component)."""
        return [f"{c}={s}" for c, states in self.component_states.items() for s in states]

    def judge_cycles(self, values: np.ndarray) -> dict[str, list[Verdict]]:
        """Per component, one verdict per cycle of ``values`` (n_cycles, n_channels, n_samples) on the rig's grid:
        its state (or ``unknown``, with ``reason``), probability and probabilities over its trained states, and
        ``novelty`` (above 1: no trained state explains the cycle)."""
        expected = (len(self.sensors), self.window)
        if values.ndim != 3 or values.shape[1:] != expected:
            raise DataError(f"cycles must have shape (cycles, {expected[0]}, {expected[1]}) for rig {self.rig.name}. "
                            f"Got {values.shape}.")
        out: dict[str, list[Verdict]] = {}
        for c, model in self.models.items():
            states, p = model.predict(values), model.classifier_.predict_proba(values)
            names = [str(k) for k in model.classifier_.classes_]
            novelty = model.novelty(values)
            out[c] = [Verdict(str(s), float(q.max()), dict(zip(names, map(float, q))), None if s != UNKNOWN else
                              "no trained state of the component explains the cycle (open-set rule)", float(n))
                      for s, q, n in zip(states, p, novelty)]
        return out

    def truth(self, labels: Mapping[str, np.ndarray]) -> dict[str, list[str]]:
        """Per component the models judge and ``labels`` has, each cycle's label as a state name, or ``unknown`` for
        a state the component was not trained on (what a verdict is compared with)."""
        trained = {c: {str(k) for k in m.classifier_.classes_} for c, m in self.models.items()}
        return {c: [name if name in trained[c] else UNKNOWN for name in map(state_name, labels[c])]
                for c in self.models if c in labels}

    def score(self, recording: Recording, smoothing: int = 1) -> OfflineScores:
        """Refused: the method judges a rig's cycles (:meth:`judge_cycles`), not a plant recording."""
        raise DataError(f"a cycles bundle scores the cycles of rig {self.rig.name!r}: give `hydrowatch score` the "
                        "rig's data folder. Got a recording.", recording.meta.get("source"))

    def online(self, *, smoothing: int = 1,
               unit_method: Callable[[str], HealthMethod | None] | None = None) -> WindowJudge:
        """Refused: a cycles bundle judges whole cycles (the scorer service takes them off
        ``hydro/<fleet>/<machine>/cycles``, :attr:`streams`), not sensor samples."""
        raise ParameterError("a cycles bundle judges a rig's whole cycles (rig_cycles messages on "
                             "hydro/<fleet>/<machine>/cycles, e.g. `hydrowatch replay` of an `import --rig` file), "
                             "not sensor samples.")
