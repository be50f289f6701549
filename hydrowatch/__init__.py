"""hydrowatch: which part of a hydrostatic transmission is wearing out, from three sensors.

Subpackages: ``plant`` (simulator), ``sysid`` (Box-Jenkins and NARX reference models), ``health``
(prediction-error distributions, relative entropy, verdicts), ``gap`` (sim-to-real mismatch),
``bus`` (Zenoh + Arrow), ``io`` (MCAP, Parquet, CSV).
"""

__version__ = "0.1.0"
