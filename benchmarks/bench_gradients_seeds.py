"""Draws of both NUTS paths over Stan seeds for one trajectory (issue 49, item 6): for a
scenario whose chains do not converge (sep_d1_p2_T50 at the default profile: R-hat ~1.7),
per-trajectory MCSEs mean nothing, so the paths are compared over independent runs.

One trajectory of the scenario (numpy seed 1), the default profile's NUTS settings, Stan
seeds 1..``--seeds`` with the hand-written program (autodiff) and with the analytic one; per
parameter of Omega the mean and 5/50/95 % quantiles of each run's draws; per statistic the
difference of the two paths' averages over seeds in units of its standard error (the
seed-to-seed spread of both paths).  Equal in distribution: |z| mostly below 2.

    python benchmarks/bench_gradients_seeds.py [--scenario sep_d1_p2_T50] [--seeds 8]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default="sep_d1_p2_T50")
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()

    from ssmobs.config.scenario import Scenario
    from ssmobs.config.validation import read_config_file, validate
    from ssmobs.nuts.stan_program import stan_program
    from ssmobs.stages.stan import sampler_settings
    from ssmobs.stan_backends.native import NativeBackend

    config = validate(read_config_file(REPO / "config" / "config.yaml"))
    entry = {s["name"]: s for s in config["scenarios"]}[args.scenario]
    sc = Scenario.from_config(entry)
    m = sc.model
    rng = np.random.default_rng(1)
    eta = rng.standard_normal((1, sc.T, m.state_dim))
    eps = rng.standard_normal((1, sc.T, m.obs_dim))
    _, z = m.simulate(sc.omega, sc.x0, eta, eps)
    data = m.stan_data(z[0], sc.prior_bounds())
    settings = sampler_settings(sc.stan_config(config["stan"]), 1)
    native = NativeBackend()
    out = {}
    for g in ("autodiff", "analytic"):
        prog, header = stan_program(m.slug, g)
        rows = []
        for seed in range(1, args.seeds + 1):
            kw = {} if header is None else {"user_header": header}
            d = native.sample(prog, data, seed, settings, **kw)
            row = []
            for name in m.param_names:
                v = np.asarray(d.params[name]).reshape(-1)
                row += [v.mean(), *np.quantile(v, [0.05, 0.5, 0.95])]
            rows.append(row)
        out[g] = np.array(rows)
    a, b = out["autodiff"], out["analytic"]
    se = np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b))
    zs = (b.mean(0) - a.mean(0)) / se
    labels = [f"{n} {s}" for n in m.param_names for s in ("mean", "q5", "q50", "q95")]
    for label, zz, ma, mb in zip(labels, zs, a.mean(0), b.mean(0)):
        print(f"{label:10s} autodiff {ma:+.4f} analytic {mb:+.4f} z {zz:+.2f}")
    print(f"{args.scenario}: max |z| {np.abs(zs).max():.2f} of {zs.size}")


if __name__ == "__main__":
    main()
