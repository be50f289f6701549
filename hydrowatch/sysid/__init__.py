"""System identification: Box-Jenkins (study chapter 3) and NARX (chapter 4).

Box-Jenkins workflow: :func:`preliminary_identification` (impulse response, disturbance, GPAC;
Eqs. 3.3-3.7) -> :class:`BoxJenkins` (prediction-error fit, Eqs. 3.8-3.14, initial state estimated,
starts and restarts from :mod:`hydrowatch.sysid.starts`) -> validation (Q, S, pole-zero;
Eqs. 3.17, 3.18) -> :func:`search_orders` (the study's order rules). See docs/sysid.md.

NARX: :class:`NARX` (tapped delay lines, Levenberg-Marquardt with Bayesian regularisation, Eq. 4.21)
and :func:`search_structure` (the study's delay/neuron search, Eqs. 4.22, 4.23). See docs/narx.md.
"""

from hydrowatch.sysid.boxjenkins import BoxJenkins
from hydrowatch.sysid.correlation import autocorrelation, confidence_bound, cross_correlation
from hydrowatch.sysid.gpac import gpac_table, read_gpac
from hydrowatch.sysid.narx import NARX
from hydrowatch.sysid.narx_search import search_structure
from hydrowatch.sysid.order_search import OrderSearch, search_orders
from hydrowatch.sysid.preliminary import (
    PreliminaryIdentification,
    disturbance_estimate,
    frequency_response,
    impulse_response_estimate,
    preliminary_identification,
)
from hydrowatch.sysid.validation import pole_zero_report, q_statistic, s_statistic

__all__ = [
    "NARX",
    "BoxJenkins",
    "OrderSearch",
    "PreliminaryIdentification",
    "autocorrelation",
    "confidence_bound",
    "cross_correlation",
    "disturbance_estimate",
    "frequency_response",
    "gpac_table",
    "impulse_response_estimate",
    "pole_zero_report",
    "preliminary_identification",
    "q_statistic",
    "read_gpac",
    "s_statistic",
    "search_orders",
    "search_structure",
]
