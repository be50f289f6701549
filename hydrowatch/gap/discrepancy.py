"""The output-discrepancy stage: a saved model's ``unidentified`` corrections applied after the plant.

When no catalog effect explains a recording, the gap analyser fits a sparse correction of each
coloured sensor, ``δ_s(u, ŷ, t) = Θ(u, ŷ, t)·ξ_s`` over the library of correction.py, evaluated on
the command u and the *noise-free* simulated operating point ŷ. The augmented model is then

    y_s(t) = ŷ_s(t) + δ_s(u, ŷ, t) + ε_s(t),

the plant simulation followed by an additive model-discrepancy term (Kennedy & O'Hagan 2001, used
here as a point estimate, not a Gaussian process) and the sensor noise ε. The correction reads the
noise-free trajectory, so a noisy simulation is corrected with the discrepancy of its noise-free
twin (same parameters, command and start; the plant's noise is additive on the sensors, kernel.py).

:func:`load_model` reads a model saved by ``hydrowatch gap --save-model`` with its discrepancy;
:meth:`GapModel.simulate` and :func:`simulate_states` simulate with the stage applied.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hydrowatch.errors import ParameterError
from hydrowatch.gap.correction import build_library
from hydrowatch.log import event, get_logger
from hydrowatch.plant import fleet
from hydrowatch.plant.effects import resolve_effects
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.simulator import simulate as plant_simulate
from hydrowatch.recording import SENSORS, UNITS, Recording

log = get_logger(__name__)

MODEL_SCHEMA = "hydrowatch.gap-model/1"
"""Schema tag of the saved augmented model (docs/gap.md)."""


@dataclass(frozen=True)
class SensorCorrection:
    """The additive correction of one sensor.

    Attributes
    ----------
    sensor : str
        One of SENSORS.
    terms : dict of str to float
        Library term → coefficient (sensor unit per term unit).
    settings : dict of str to float
        Library settings (``pump_speed`` rad/s, ``rate_scale`` V/s; ``Library.settings``). Empty for
        models saved before they were stored: the rate scale is then taken from the trajectory.
    """

    sensor: str
    terms: dict[str, float]
    settings: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Discrepancy:
    """The output-discrepancy stage δ(u, ŷ, t), one additive correction per corrected sensor.

    Attributes
    ----------
    corrections : tuple of SensorCorrection
    """

    corrections: tuple[SensorCorrection, ...]

    @classmethod
    def from_config(cls, config: Mapping[str, Any], pump_speed: float) -> Discrepancy:
        """From a saved model's ``corrections`` object ``{sensor: {"unit", "terms", "library"}}``.

        ``pump_speed`` (rad/s, the model's ωp) fills in a missing ``library.pump_speed``.

        Raises
        ------
        ParameterError
            An unknown sensor or library term, or a non-finite coefficient.
        """
        names = set(build_library(np.zeros(8), np.zeros((3, 8)), np.arange(8.0), pump_speed=1.0).names)
        out = []
        for sensor, entry in config.items():
            if sensor not in SENSORS:
                raise ParameterError(f"correction sensor must be one of {SENSORS}. Got '{sensor}'. "
                                     "Fix the model file's 'corrections'.")
            terms = {str(k): float(v) for k, v in dict(entry.get("terms", {})).items()}
            unknown = sorted(set(terms) - names)
            if unknown or not all(np.isfinite(v) for v in terms.values()):
                raise ParameterError(f"correction terms must be finite coefficients of library terms {sorted(names)}. "
                                     f"Got {terms}. Re-save the model with 'hydrowatch gap --save-model'.")
            settings = {str(k): float(v) for k, v in dict(entry.get("library", {})).items()}
            settings.setdefault("pump_speed", float(pump_speed))
            if "rate_scale" not in settings:
                event(log, "correction without library.rate_scale (an older model): taken from each command",
                      level=logging.WARNING, sensor=sensor)
            out.append(SensorCorrection(sensor, terms, settings))
        return cls(tuple(out))

    def to_config(self) -> dict[str, Any]:
        """The saved model's ``corrections`` object (inverse of :meth:`from_config`)."""
        return {c.sensor: {"unit": UNITS[c.sensor], "terms": dict(c.terms), "library": dict(c.settings)}
                for c in self.corrections}

    def __call__(self, voltage: np.ndarray, simulated: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The discrepancy δ, shape (3, n), sensor units (zero rows for uncorrected sensors).

        Parameters
        ----------
        voltage : ndarray, shape (n,)
            Command, V.
        simulated : ndarray, shape (3, n)
            Noise-free simulated flow [L/min], speed [rad/s], torque [N·m].
        t : ndarray, shape (n,)
            Sample times, s.
        """
        delta = np.zeros_like(np.asarray(simulated, dtype=np.float64))
        for c in self.corrections:
            library = build_library(voltage, simulated, t, pump_speed=c.settings["pump_speed"],
                                    rate_scale=c.settings.get("rate_scale"))
            for name, coef in c.terms.items():
                delta[SENSORS.index(c.sensor)] += coef * library.column(name)
        return delta

    def apply(self, recording: Recording, clean: Recording | None = None) -> Recording:
        """A simulated recording with the discrepancy added to its sensors.

        Parameters
        ----------
        recording : Recording
            A simulation (noisy or not) of the plant.
        clean : Recording, optional
            Its noise-free twin (same parameters, command and start), the operating point δ reads;
            default: ``recording`` itself (right when it was simulated without noise).
        """
        point = clean if clean is not None else recording
        simulated = np.vstack([point[s] for s in SENSORS])
        delta = self(point["voltage"], simulated, point.t)
        channels = dict(recording.channels)
        for i, s in enumerate(SENSORS):
            if np.any(delta[i]):
                channels[s] = recording[s] + delta[i]
        return Recording(recording.t, channels, {**recording.meta, "discrepancy": self.to_config()})


@dataclass(frozen=True)
class GapModel:
    """A model saved by ``hydrowatch gap --save-model`` (or a flat parameters file).

    Attributes
    ----------
    parameters : PlantParameters
    effects : dict
        Simulator effects, catalog units.
    discrepancy : Discrepancy or None
        The output-discrepancy stage (None when the model has no corrections).
    """

    parameters: PlantParameters
    effects: dict[str, dict[str, float]]
    discrepancy: Discrepancy | None = None

    def simulate(self, voltage: np.ndarray, *, noise: bool = True, seed: int | None = None,
                 meta: dict[str, Any] | None = None) -> Recording:
        """The plant simulation (settled at the first command) followed by the discrepancy stage.

        Parameters as :func:`hydrowatch.plant.simulator.simulate`; returns its Recording with the
        corrected sensors.
        """
        rec = plant_simulate(voltage, self.parameters, self.effects, noise=noise, seed=seed, meta=meta)
        if self.discrepancy is None:
            return rec
        clean = plant_simulate(voltage, self.parameters, self.effects, noise=False) if noise else None
        return self.discrepancy.apply(rec, clean)


def model_from_config(data: Mapping[str, Any]) -> GapModel:
    """A :class:`GapModel` from a saved model object (MODEL_SCHEMA) or a flat parameters object."""
    if data.get("schema") != MODEL_SCHEMA:
        return GapModel(PlantParameters.from_dict(dict(data)), {})
    parameters = PlantParameters.from_dict(data["parameters"])
    corrections = data.get("corrections") or {}
    discrepancy = Discrepancy.from_config(corrections, parameters.omega_p) if corrections else None
    return GapModel(parameters, resolve_effects(data.get("effects")), discrepancy)


def load_model(path: str | Path) -> GapModel:
    """Read a saved model (MODEL_SCHEMA) or a flat parameters JSON file.

    Raises
    ------
    ParameterError
        A missing file, invalid JSON, unknown parameter names, effects out of the catalog's ranges or
        corrections with unknown terms.
    """
    if not Path(path).is_file():
        raise ParameterError(f"model file must exist. Got '{path}'. Give a JSON file written by --save-model.")
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ParameterError(f"{path} must be valid JSON. Got an error: {exc}.") from None
    if not isinstance(data, dict):
        raise ParameterError(f"{path} must hold a JSON object. Got {type(data).__name__}. Give a parameters object "
                             "or a model saved by --save-model.")
    return model_from_config(data)


def simulate_states(model: GapModel, states: Sequence[str], *, noise: bool = True, **kwargs: Any
                    ) -> Iterator[Recording]:
    """:func:`hydrowatch.plant.fleet.simulate_states` of a saved model, with its discrepancy stage.

    Each state's recording is corrected with the discrepancy of its own noise-free twin (the
    correction is a property of the machine, like its effects; faults change the operating point
    it reads). ``kwargs`` as :func:`hydrowatch.plant.fleet.simulate_states` (``effects`` replace
    the model's).
    """
    kwargs.setdefault("effects", model.effects)
    recordings = fleet.simulate_states(states, nominal=model.parameters, noise=noise, **kwargs)
    if model.discrepancy is None:
        yield from recordings
        return
    twins = fleet.simulate_states(states, nominal=model.parameters, noise=False, **kwargs) if noise else None
    for rec in recordings:
        clean = next(twins) if twins is not None else None
        yield model.discrepancy.apply(rec, clean)


__all__ = ["MODEL_SCHEMA", "Discrepancy", "GapModel", "SensorCorrection", "load_model", "model_from_config",
           "simulate_states"]
