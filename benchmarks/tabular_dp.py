"""Speed of exact DP in taskrl.tabular on random sparse MDPs.

For S in {1e3, 1e4, 1e5} states x A = 10 actions, each (s, a) with 3-5 random successors:

* the lower bound: one sparse mat-vec ``gamma P @ V`` with the ``[A * S, S]`` matrix a sweep uses;
* one value-iteration sweep (measured as the difference between runs of N2 and N1 sweeps of
  ``value_iteration``, so fixed costs cancel);
* one policy-iteration improvement step (Bellman backup + greedy policy, the code
  ``policy_iteration`` runs) and one exact evaluation step (``evaluate_policy``, auto solver);
* a straightforward per-state Python loop doing the same sweep (lists, no numpy).

Usage::

    .venv/bin/python benchmarks/tabular_dp.py            # markdown table on stdout
    .venv/bin/python benchmarks/tabular_dp.py --sizes 1000 10000 --repeats 3
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import time

import numpy as np
import scipy
import scipy.sparse as sp

from taskrl.tabular import FiniteMDP, evaluate_policy, policy_iteration, value_iteration
from taskrl.tabular.dp import _backup, _greedy_am


def random_sparse_mdp(S: int, A: int, gamma: float, seed: int) -> FiniteMDP:
    """Each (s, a) moves to 3-5 uniformly random successors with random probabilities."""
    rng = np.random.default_rng(seed)
    k = rng.integers(3, 6, size=S * A)
    indptr = np.concatenate([[0], np.cumsum(k)])
    indices = rng.integers(0, S, size=indptr[-1])
    data = rng.exponential(size=indptr[-1])
    data /= np.repeat(np.add.reduceat(data, indptr[:-1]), k)
    P = sp.csr_matrix((data, indices, indptr), shape=(S * A, S))
    return FiniteMDP(P, rng.uniform(0.0, 1.0, size=(S, A)), gamma)


def per_call(fn, min_seconds: float = 0.2) -> float:
    """Mean seconds per call over a loop lasting at least ``min_seconds``."""
    fn()
    n, total = 0, 0.0
    t0 = time.perf_counter()
    while n == 0 or total < min_seconds:
        fn()
        n += 1
        total = time.perf_counter() - t0
    return total / n


def naive_sweep(rows: list, R: list, V: list, gamma: float, states: range) -> list:
    """One value-iteration sweep written the straightforward way: loops over s, a, s'."""
    out = []
    for s in states:
        best = -float("inf")
        for a, successors in enumerate(rows[s]):
            q = R[s][a]
            for s2, p in successors:
                q += gamma * p * V[s2]
            if q > best:
                best = q
        out.append(best)
    return out


def bench(S: int, A: int, gamma: float, repeats: int, seed: int, naive_max: int, lu_max: int) -> dict:
    mdp = random_sparse_mdp(S, A, gamma, seed)
    gP = mdp.discounted_transitions
    rng = np.random.default_rng(seed + 1)
    V = rng.uniform(0, 1 / (1 - gamma), size=S)
    policy = rng.integers(0, A, size=S)
    n1, n2 = 5, 25
    matvec, sweep, improve, evaluate = [], [], [], []
    for _ in range(repeats):  # interleaved, so that background load hits all alike
        matvec.append(per_call(lambda: gP @ V))
        t1 = value_iteration(mdp, tol=0.0, max_iterations=n1).seconds
        t2 = value_iteration(mdp, tol=0.0, max_iterations=n2).seconds
        sweep.append((t2 - t1) / (n2 - n1))
        improve.append(per_call(lambda: _greedy_am(_backup(mdp, V), policy, 1e-10)))
        evaluate.append(per_call(lambda: evaluate_policy(mdp, policy), min_seconds=0.0))
    med = statistics.median
    # Exact sparse LU of the same system, once (fill-in makes it explode on random MDPs).
    lu = per_call(lambda: evaluate_policy(mdp, policy, solver="sparse"), min_seconds=0.0) if S <= lu_max else None

    # Naive loop on Python lists (the conversion is not timed).
    P = mdp.P  # state-major, row s * A + a
    n_naive = min(S, naive_max)
    rows = [
        [
            list(
                zip(
                    P.indices[P.indptr[s * A + a] : P.indptr[s * A + a + 1]].tolist(),
                    P.data[P.indptr[s * A + a] : P.indptr[s * A + a + 1]].tolist(),
                )
            )
            for a in range(A)
        ]
        for s in range(n_naive)
    ]
    R, Vl = mdp.R.tolist(), V.tolist()
    t0 = time.perf_counter()
    naive = naive_sweep(rows, R, Vl, gamma, range(n_naive))
    naive_s = (time.perf_counter() - t0) * S / n_naive
    ref = _backup(mdp, V).max(axis=0)[:n_naive]
    assert np.allclose(naive, ref), "naive sweep disagrees with the vectorised one"

    pi_sol = policy_iteration(mdp)
    vi_sol = value_iteration(mdp, tol=1e-6)
    return {
        "S": S,
        "nnz": gP.nnz,
        "matvec": med(matvec),
        "sweep": med(sweep),
        "improve": med(improve),
        "evaluate": med(evaluate),
        "lu": lu,
        "naive": naive_s,
        "naive_extrapolated": n_naive < S,
        "pi_iters": pi_sol.iterations,
        "pi_time": pi_sol.seconds,
        "vi_iters": vi_sol.iterations,
        "vi_time": vi_sol.seconds,
        "agree": float(np.abs(pi_sol.values - vi_sol.values).max()),
    }


def fmt_t(x: float) -> str:
    if x >= 1.0:
        return f"{x:.3g} s"
    return f"{x * 1e3:.3g} ms" if x >= 1e-3 else f"{x * 1e6:.3g} µs"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1_000, 10_000, 100_000], help="numbers of states")
    ap.add_argument("--actions", type=int, default=10, help="actions per state")
    ap.add_argument("--gamma", type=float, default=0.95, help="discount")
    ap.add_argument("--repeats", type=int, default=5, help="interleaved repeats; medians are reported")
    ap.add_argument("--seed", type=int, default=0, help="random seed")
    ap.add_argument(
        "--lu-max-states", type=int, default=1_000, help="also time the sparse-LU evaluation up to this many states (1e4: ~20 s)"
    )
    ap.add_argument(
        "--naive-max-states",
        type=int,
        default=100_000,
        help="time the Python loop on at most this many states and extrapolate linearly",
    )
    args = ap.parse_args()

    cpu = next(
        (line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")), platform.processor()
    )
    print(f"- date: {datetime.datetime.now().isoformat(timespec='minutes')}")
    print(f"- machine: {cpu}, {os.cpu_count()} cores; load average at start {os.getloadavg()[0]:.2f}")
    print(f"- python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}")
    print(f"- A = {args.actions}, 3-5 successors per (s, a), gamma = {args.gamma}, medians of {args.repeats} repeats\n")
    print(
        "| S | nnz(P) | P @ V (lower bound) | VI sweep | VI / matvec | PI improvement | PI impr. / matvec "
        "| PI evaluation (BiCGSTAB) | eval / matvec | eval by sparse LU | naive Python sweep | naive / VI | PI: rounds, total | VI to 1e-6: sweeps, total |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for S in args.sizes:
        r = bench(S, args.actions, args.gamma, args.repeats, args.seed, args.naive_max_states, args.lu_max_states)
        lu = "-" if r["lu"] is None else fmt_t(r["lu"])
        naive = fmt_t(r["naive"]) + (" (extrapolated)" if r["naive_extrapolated"] else "")
        print(
            f"| {S:,} | {r['nnz']:,} | {fmt_t(r['matvec'])} | {fmt_t(r['sweep'])} | {r['sweep'] / r['matvec']:.2f}x "
            f"| {fmt_t(r['improve'])} | {r['improve'] / r['matvec']:.2f}x | {fmt_t(r['evaluate'])} "
            f"| {r['evaluate'] / r['matvec']:.1f}x | {lu} | {naive} | {r['naive'] / r['sweep']:.0f}x "
            f"| {r['pi_iters']}, {fmt_t(r['pi_time'])} | {r['vi_iters']}, {fmt_t(r['vi_time'])} |",
            flush=True,
        )
        assert r["agree"] < 1e-4, f"PI and VI disagree by {r['agree']}"


if __name__ == "__main__":
    main()
