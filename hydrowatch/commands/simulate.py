"""``hydrowatch simulate``: offline simulation, one labelled recording per health state.

Writes ``<state>.<format>`` into ``--out`` for every requested state and prints a JSON summary
(``out``, ``format``, ``files``, ``states``, ``seconds``, ``volts``, ``seed``, ``noise``,
``effects``, ``command``) on stdout. The default length is 120 s per state (24,000 samples, a
quick data set); ``--seconds 1250`` gives the study's full data set per state. The maths lives in
:func:`hydrowatch.plant.fleet.simulate_states`. With ``--degrade FAULT:FROM:TO:SECONDS[:linear|exp]`` (repeatable)
it writes instead one ``degrade_<FAULT>.<format>`` per path, a part wearing from index FROM to TO
(:mod:`hydrowatch.plant.paths`), labelled per sample; the summary then adds ``degrade``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from hydrowatch.errors import ParameterError
from hydrowatch.plant.effects import Effects, parse_effects
from hydrowatch.plant.excitation import filtered_noise, n_samples, parse_volts, read_command
from hydrowatch.plant.faults import EXTENDED_STATES, STUDY_STATES, parse_state
from hydrowatch.plant.fleet import state_seeds
from hydrowatch.plant.parameters import PlantParameters
from hydrowatch.plant.paths import FORM, parse_degradation, simulate_path
from hydrowatch.plant.wear import DegradationPath
from hydrowatch.recording import SAMPLE_RATE_HZ

if TYPE_CHECKING:
    from hydrowatch.gap.discrepancy import GapModel

NAME = "simulate"
HELP = "simulate the plant offline: one labelled recording per health state (<state>.mcap|parquet)"

DEFAULT_SECONDS = 120.0
"""Seconds per state when --seconds is not given (the study used 1250 s per state)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of the contract (../shared/docs/contract.md)."""
    parser.add_argument("--out", required=True, type=Path, help="output folder (created if missing)")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--states",
                       help=f"comma-separated health states (default: the study's 7: {','.join(STUDY_STATES)})")
    which.add_argument("--extended", action="store_true", help="all 13 states (healthy + 6 faults × warning, alert)")
    parser.add_argument("--seconds", type=float, default=DEFAULT_SECONDS,
                        help=f"seconds per state (default {DEFAULT_SECONDS:g}; the study used 1250)")
    parser.add_argument("--volts", default="0:4",
                        help="voltage range LO:HI of the filtered-noise command (default 0:4)")
    parser.add_argument("--command", type=Path, help="replay the 'voltage' column of a CSV/Parquet file instead")
    parser.add_argument("--no-noise", action="store_true", help="no sensor noise")
    parser.add_argument("--effects", default="", help="effects to switch on: 'id[:k=v,...];id2' (plant-model.md)")
    parser.add_argument("--nominal", type=Path,
                        help="healthy-machine parameters, JSON: flat parameters or a model saved by "
                             "'hydrowatch gap --save-model' (its effects are switched on too, --effects adds to "
                             "them; its corrections are added to the simulated sensors)")
    parser.add_argument("--format", choices=("mcap", "parquet"), default="mcap", help="file format (default mcap)")
    parser.add_argument("--seed", type=int, default=0, help="data set seed; each state derives its own (default 0)")
    parser.add_argument("--degrade", action="append", default=None, metavar=FORM,
                        help="instead of the states, one recording degrade_<FAULT>.<format> of a part wearing: its "
                             "degradation index (0 new, 0.5 warning, 1 alert) goes FROM -> TO over SECONDS, linear "
                             "or exp (accelerating); the recording lasts SECONDS (or the --command); repeatable")


def _states(args: argparse.Namespace) -> list[str]:
    if args.extended:
        return list(EXTENDED_STATES)
    if args.states is None:
        return list(STUDY_STATES)
    states = [s.strip() for s in args.states.split(",") if s.strip()]
    if not states:
        raise ParameterError(f"--states must name at least one state. Got {args.states!r}.")
    for state in states:
        parse_state(state)
    if len(set(states)) != len(states):
        raise ParameterError(f"--states must not repeat a state. Got {states}.")
    return states


def run(args: argparse.Namespace) -> int:
    """Simulate, write one file per state, print the JSON summary; returns 0."""
    from hydrowatch.gap.discrepancy import GapModel, load_model, simulate_states
    from hydrowatch.io import write_recording

    paths = [parse_degradation(spec) for spec in args.degrade or []]
    states = [] if paths else _states(args)
    volts = parse_volts(args.volts)
    model = load_model(args.nominal) if args.nominal is not None else GapModel(PlantParameters(), {})
    effects = {**model.effects, **parse_effects(args.effects)}
    command = read_command(args.command) if args.command is not None else None
    seconds = command.size / SAMPLE_RATE_HZ if command is not None else n_samples(args.seconds) / SAMPLE_RATE_HZ
    args.out.mkdir(parents=True, exist_ok=True)
    files = []
    # a saved model's corrections run as an output-discrepancy stage after the plant (gap/discrepancy.py)
    recordings = simulate_states(model, states, seconds=seconds, volts=volts, command=command, effects=effects,
                                 noise=not args.no_noise, seed=args.seed)
    for state, recording in tqdm(zip(states, recordings), total=len(states), desc="states", unit="state",
                                 file=sys.stderr, disable=None):
        path = args.out / f"{state}.{args.format}"
        write_recording(recording, path)
        files.append(str(path))
    for path in paths:
        files.append(str(_write_path(args, path, command, volts, model, effects)))
    summary = {
        "out": str(args.out), "format": args.format, "files": files, "states": states, "seconds": seconds,
        "volts": None if command is not None else list(volts), "seed": args.seed, "noise": not args.no_noise,
        "effects": effects, "command": None if args.command is None else str(args.command),
        "corrections": None if model.discrepancy is None else model.discrepancy.to_config(),
    }
    if paths:
        summary["degrade"] = list(args.degrade)
    print(json.dumps(summary))
    return 0


def _write_path(args: argparse.Namespace, path: DegradationPath, command: np.ndarray | None, volts: tuple[float, float],
                model: GapModel, effects: Effects) -> Path:
    """Simulate and write one ``--degrade`` recording; its command lasts the path (or is the --command)."""
    from hydrowatch.io import write_recording

    name = f"degrade_{path.fault}"
    command_seed, noise_seed = state_seeds(args.seed, name)
    u = command if command is not None else filtered_noise(path.duration_s, volts, seed=command_seed)
    out = args.out / f"{name}.{args.format}"
    write_recording(simulate_path(path, u, nominal=model.parameters, effects=effects, noise=not args.no_noise,
                                  seed=noise_seed), out)
    return out
