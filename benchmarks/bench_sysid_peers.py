"""Peers: hydrowatch's Box-Jenkins and NARX against SIPPY's BJ and SysIdentPy's neural NARX, same data.

Run it with the peers' own environment (they are not project dependencies), one line:

    benchmarks/peers/.venv/bin/python benchmarks/bench_sysid_peers.py [--quick]

Set that environment up once (gitignored; torch first, so pip keeps the CPU build on disk):

    python3 -m venv benchmarks/peers/.venv && benchmarks/peers/.venv/bin/pip install torch==2.13.0 \
        && benchmarks/peers/.venv/bin/pip install sippy-unipi sysidentpy -c <(echo torch==2.13.0)

The script runs itself a second time with the project's interpreter (``.venv/bin/python`` or
``$HYDROWATCH_PYTHON``) as ``--ours FILE``: that run generates the data and fits hydrowatch's
models, and writes both to an .npz; the peers then fit the very same arrays. Data:

- Box-Jenkins: the study's Eq. 3.24 (orders 4, 4, 4, 5, delay 4), input of Eq. 3.21, noise
  sigma 0.5; N = 10,000 to fit (3,000 with --quick), 4,000 held out. Accuracy: max |theta - theta_true|
  and one-step NRMSE on the held-out samples.
- NARX: the simulated healthy plant, filtered noise over 0-4 V, gearbox speed, 200 Hz; 10,000
  samples to fit (3,000 with --quick), 4,000 held out; delay lines 15/15, 35 neurons (Table 4.5);
  SysIdentPy trains 50 Adam epochs (10 with --quick): one epoch of 10,000 samples took ~5 s.

SIPPY's BJ solves one CasADi/IPOPT problem with the whole output trajectory as unknowns: about a
minute at 3,000 samples, many minutes at 10,000. A full run takes 15-30 min on a loaded 2-core
machine; --quick about 3 min.

NRMSE = RMS(y - y_hat) / std(y) over the held-out samples after the first 20. Times are wall
clock on whatever machine runs it: on a shared one they are pessimistic for every column alike.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HELD_OUT = 4_000
SKIP = 20
EQ_3_24 = {  # the study's Eq. 3.24 (Table 3.11); repeated so the peers' run needs no hydrowatch
    "b": [1.6051, 0.6470, -0.4455, 1.0721],
    "f": [-1.6347, -0.1301, 1.3594, -0.5819],
    "c": [-1.2158, 0.8683, -0.4533, 0.2314],
    "d": [-1.3915, 1.0989, -0.8340, 0.4274, -0.1449],
    "delay": 4,
}


def nrmse(y: np.ndarray, y_hat: np.ndarray) -> float:
    """RMS(y - y_hat) / std(y) after the first SKIP samples."""
    y, y_hat = np.asarray(y)[SKIP:], np.asarray(y_hat).ravel()[SKIP:]
    return float(np.sqrt(np.mean((y - y_hat) ** 2)) / np.std(y))


def theta_true() -> np.ndarray:
    return np.concatenate([EQ_3_24[k] for k in ("b", "f", "c", "d")])


# ---------------------------------------------------------------- hydrowatch side (project venv)
def ours(path: Path, quick: bool) -> None:
    """Generate both data sets, fit hydrowatch's models, write arrays and results to ``path``."""
    sys.path.insert(0, str(ROOT))
    from hydrowatch.plant.excitation import filtered_noise
    from hydrowatch.plant.simulator import simulate
    from hydrowatch.sysid import NARX, BoxJenkins, search_orders
    from hydrowatch.sysid.narx_lines import linear_one_step
    from hydrowatch.sysid.pem import filtered_white_noise, simulate_box_jenkins

    n_fit = 3_000 if quick else 10_000
    rng = np.random.default_rng(0)
    u = filtered_white_noise(n_fit + HELD_OUT, rng)
    m = EQ_3_24
    y = simulate_box_jenkins(m["b"], m["f"], m["c"], m["d"], 4, u, 0.5 * rng.standard_normal(u.size))
    results: dict[str, Any] = {"n_fit": n_fit}
    start = time.perf_counter()
    bj = BoxJenkins(nb=4, nf=4, nc=4, nd=5, delay=4).fit(u[:n_fit], y[:n_fit])
    theta = np.concatenate([bj.b_, bj.f_, bj.c_, bj.d_])
    results["bj"] = {"seconds": time.perf_counter() - start, "error": float(np.max(np.abs(theta - theta_true()))),
                     "nrmse": nrmse(y[n_fit:], bj.predict(u[n_fit:], y[n_fit:]))}  # fmt: skip

    command = filtered_noise((n_fit + HELD_OUT) / 200.0, (0.0, 4.0), seed=1)
    record = simulate(command, seed=2)
    pu, py = record.channels["voltage"], record.channels["speed"]
    start = time.perf_counter()
    narx = NARX(input_delays=15, output_delays=15, hidden=35, max_iter=40 if quick else 200).fit(pu[:n_fit], py[:n_fit])
    seconds = time.perf_counter() - start
    results["narx"] = {"seconds": seconds, "nrmse": nrmse(py[n_fit:], narx.predict(pu[n_fit:], py[n_fit:])),
                       "iterations": narx.summary()["iterations"]}  # fmt: skip
    arx = linear_one_step(pu[:n_fit], py[:n_fit], pu[n_fit:], py[n_fit:], 15, 15)
    results["arx"] = {"nrmse": nrmse(py[n_fit:], arx)}
    searched = search_orders(pu[:n_fit], py[:n_fit])
    results["bj_plant"] = {"orders": searched.orders,
                           "nrmse": nrmse(py[n_fit:], searched.model.predict(pu[n_fit:], py[n_fit:]))}  # fmt: skip
    np.savez(path, bj_u=u, bj_y=y, plant_u=pu, plant_y=py, results=json.dumps(results))


# ---------------------------------------------------------------------- peers' side (peer venv)
def sippy_bj(u: np.ndarray, y: np.ndarray, n_fit: int, **options: Any) -> dict[str, Any]:
    """SIPPY's BJ (CasADi/IPOPT) with the true orders; its theta is our delay K (b1 at q^-(K+1))."""
    from sippy_unipi import system_identification

    start = time.perf_counter()
    # BJ_orders = [nb, nc, nd, nf, theta]
    model = system_identification(y[:n_fit], u[:n_fit], "BJ", BJ_orders=[4, 4, 5, 4, 4], **options)
    seconds = time.perf_counter() - start
    num = np.r_[0.0, np.ravel(model.NUMERATOR[0][0])]  # coefficients of q^0, q^-1, ...
    den = np.ravel(model.DENOMINATOR[0][0])
    c_full, d_full = np.ravel(model.NUMERATOR_H[0][0]), np.ravel(model.DENOMINATOR_H[0][0])
    theta = np.concatenate([num[5:9], den[1:5], c_full[1:5], d_full[1:6]])
    from scipy.signal import lfilter

    u_t, y_t = u[n_fit:], y[n_fit:]
    roots = np.abs(np.roots(c_full)) if c_full.size > 1 else np.zeros(0)
    if roots.size and roots.max() >= 1.0:  # the predictor D/C (Eq. 3.26) diverges
        prediction = f"predictor unstable (|zero of C| = {roots.max():.2f})"
    else:
        prediction = nrmse(y_t, y_t - lfilter(d_full, c_full, y_t - lfilter(num, den, u_t)))
    return {"seconds": seconds, "error": float(np.max(np.abs(theta - theta_true()))), "nrmse": prediction}


def sysidentpy_narx(u: np.ndarray, y: np.ndarray, n_fit: int, epochs: int) -> dict[str, Any]:
    """SysIdentPy's NARXNN, lines 15/15 into 35 log-sigmoid neurons and a linear output, Adam."""
    import torch
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.neural_network import NARXNN

    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(30, 35), torch.nn.Sigmoid(), torch.nn.Linear(35, 1))
    mu, mu_y, su, sy = u[:n_fit].mean(), y[:n_fit].mean(), u[:n_fit].std(), y[:n_fit].std()
    model = NARXNN(net=net, ylag=15, xlag=15, basis_function=Polynomial(degree=1), model_type="NARMAX",
                   loss_func="mse_loss", optimizer="Adam", epochs=epochs, batch_size=100,
                   learning_rate=1e-3)  # fmt: skip
    start = time.perf_counter()
    model.fit(X=((u[:n_fit] - mu) / su)[:, None], y=((y[:n_fit] - mu_y) / sy)[:, None])
    seconds = time.perf_counter() - start
    y_hat = model.predict(X=((u[n_fit:] - mu) / su)[:, None], y=((y[n_fit:] - mu_y) / sy)[:, None], steps_ahead=1)
    return {"seconds": seconds, "nrmse": nrmse(y[n_fit:], np.ravel(y_hat) * sy + mu_y), "epochs": epochs}


def attempt(name: str, job: Any) -> dict[str, Any]:
    """Run one peer; on failure record exactly what happened instead of a number."""
    try:
        return dict(job())
    except Exception as exc:  # noqa: BLE001 - a third-party package: report what it raised and go on
        return {"failed": f"{type(exc).__name__}: {exc}"[:300], "name": name}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="3,000 fit samples, 40 LM iterations, 10 epochs")
    parser.add_argument("--ours", type=Path, help=argparse.SUPPRESS)  # internal: the project-venv half
    args = parser.parse_args()
    if args.ours is not None:
        ours(args.ours, args.quick)
        return
    python = os.environ.get("HYDROWATCH_PYTHON", str(ROOT / ".venv" / "bin" / "python"))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "data.npz"
        call = [python, str(Path(__file__).resolve()), "--ours", str(path)] + (["--quick"] if args.quick else [])
        subprocess.run(call, check=True, cwd=ROOT)
        data = np.load(path)
        arrays = {k: np.array(data[k]) for k in ("bj_u", "bj_y", "plant_u", "plant_y")}
        results = json.loads(str(data["results"]))
    n_fit = int(results["n_fit"])
    sippy = attempt("sippy", lambda: sippy_bj(arrays["bj_u"], arrays["bj_y"], n_fit, max_iterations=200))
    sippy_stable = attempt("sippy", lambda: sippy_bj(arrays["bj_u"], arrays["bj_y"], n_fit, max_iterations=200,
                                                     stab_cons=True, stab_marg=0.99))  # fmt: skip
    sid = attempt("sysidentpy", lambda: sysidentpy_narx(arrays["plant_u"], arrays["plant_y"], n_fit,
                                                          10 if args.quick else 50))  # fmt: skip
    print(f"Box-Jenkins, Eq. 3.24 (4,4,4,5; K=4), {n_fit} samples to fit, {HELD_OUT} held out")
    print("| estimator | fit time [s] | max abs parameter error | held-out one-step NRMSE |")
    print("|---|---|---|---|")
    ours_bj = results["bj"]
    print(f"| hydrowatch BoxJenkins (LM, exact Jacobian) | {ours_bj['seconds']:.2f} | {ours_bj['error']:.3f} "
          f"| {ours_bj['nrmse']:.4f} |")  # fmt: skip
    print(_row("SIPPY BJ (CasADi/IPOPT, 200 iterations)", sippy, ours_bj["seconds"]))
    print(_row("SIPPY BJ, stability constraint (stab_cons, margin 0.99)", sippy_stable, ours_bj["seconds"]))
    print(f"\nNARX, plant 0-4 V gearbox speed, lines 15/15, 35 neurons, {n_fit} samples to fit, {HELD_OUT} held out")
    print("| estimator | fit time [s] | held-out one-step NRMSE |")
    print("|---|---|---|")
    n = results["narx"]
    print(f"| hydrowatch NARX (LM + Bayesian regularisation, {n['iterations']} it.) | {n['seconds']:.1f} "
          f"| {n['nrmse']:.4f} |")  # fmt: skip
    print(_row(f"SysIdentPy NARXNN (Adam, {sid.get('epochs', '?')} epochs)", sid, n["seconds"], error=False))
    print(f"| linear ARX 15/15 (least squares) | - | {results['arx']['nrmse']:.4f} |")
    bp = results["bj_plant"]
    print(f"| hydrowatch BoxJenkins, orders by search_orders {bp['orders']} | - | {bp['nrmse']:.4f} |")


def _row(label: str, peer: dict[str, Any], ours_seconds: float, error: bool = True) -> str:
    if "failed" in peer:
        return f"| {label} | failed: {peer['failed']} |" + (" |" if error else "") + " |"
    ratio = f" ({peer['seconds'] / ours_seconds:.0f}x hydrowatch)" if ours_seconds > 0 else ""
    middle = f" {peer['error']:.3f} |" if error else ""
    score = peer["nrmse"] if isinstance(peer["nrmse"], str) else f"{peer['nrmse']:.4f}"
    return f"| {label} | {peer['seconds']:.2f}{ratio} |{middle} {score} |"


if __name__ == "__main__":
    main()
