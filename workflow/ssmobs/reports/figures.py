"""Paper figures (seaborn/matplotlib); each function writes PDF and PNG atomically."""

from __future__ import annotations

import os
from collections.abc import Sequence
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from .. import io

if TYPE_CHECKING:
    import pandas
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


def _plt() -> ModuleType:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import seaborn as sns

    sns.set_theme(style="whitegrid", context="paper")
    return plt


def save_figure(fig: Figure, paths: Sequence[str | os.PathLike]) -> None:
    """Save one figure to several formats atomically (format from each path's suffix).

    PDF metadata dates are removed so that reruns give identical bytes.
    """
    for path in paths:
        path = os.fspath(path)
        ext = os.path.splitext(path)[1].lstrip(".")
        meta = {"CreationDate": None} if ext == "pdf" else {"Software": None}
        with io.atomic_path(path) as tmp:
            fig.savefig(tmp, format=ext, dpi=150, bbox_inches="tight", metadata=meta)


def _gauss_contours(
    ax: Axes, mean: np.ndarray, cov: np.ndarray, span: float = 3.2, levels: int = 6
) -> None:
    sd = np.sqrt(np.diag(cov))
    gx = np.linspace(mean[0] - span * sd[0], mean[0] + span * sd[0], 200)
    gy = np.linspace(mean[1] - span * sd[1], mean[1] + span * sd[1], 200)
    X, Y = np.meshgrid(gx, gy)
    d = np.stack([X - mean[0], Y - mean[1]], axis=-1)
    inv = np.linalg.inv(cov)
    dens = np.exp(-0.5 * np.einsum("...i,ij,...j->...", d, inv, d))
    dens /= 2 * np.pi * np.sqrt(np.linalg.det(cov))
    ax.contour(X, Y, dens, levels=levels, cmap="Blues", linewidths=0.9)


def figure_design_points(
    disturbances: np.ndarray, a: float, x0: float, paths: Sequence[str | os.PathLike]
) -> None:
    """Figure 2 (Sec. III.A, Example 5): design disturbances (eta_1, eps_1) over N(0, I_2)
    and the design values (x~_1, z~_1) of model Same over the density of (X_1, Z_1).
    """
    from ..models import get_model

    plt = _plt()
    model = get_model("same")
    x, z = model.design_trajectories([a], [x0], disturbances, T=1)
    s2 = 1 - a**2
    mean = np.array([a * x0, a * a * x0])
    cov = np.array([[s2, a * s2], [a * s2, a * a * s2 + s2]])
    fig, (left, right) = plt.subplots(1, 2, figsize=(8.0, 3.6))
    _gauss_contours(left, np.zeros(2), np.eye(2))
    left.scatter(disturbances[0], disturbances[1], color="crimson", zorder=3, s=30)
    left.set_xlabel(r"$\tilde\eta_1^{(k)}$")
    left.set_ylabel(r"$\tilde\epsilon_1^{(k)}$")
    left.set_title(f"{disturbances.shape[1]} design disturbances, N(0, I$_2$)")
    left.set_aspect("equal")
    _gauss_contours(right, mean, cov)
    right.scatter(x[:, 0, 0], z[:, 0, 0], color="crimson", zorder=3, s=30)
    right.set_xlabel(r"$\tilde x_1^{(k)}$")
    right.set_ylabel(r"$\tilde z_1^{(k)}$")
    right.set_title(rf"Same: $a$={a}, $x_0$={x0}")
    fig.tight_layout()
    save_figure(fig, paths)
    plt.close(fig)


def figure_joint_vs_marginal(
    panels: list[dict],
    omega_true: float,
    x0_true: float,
    paths: Sequence[str | os.PathLike],
    name: str = "a",
) -> None:
    """Figure 3 (Sec. IV.A): pairwise scatter of joint-MAP estimates (a^, x0^) over K^max
    (left) and marginal-MAP estimates over K^Stan (right), one colour per T; true values as
    lines.  ``panels``: dicts with ``T``, ``joint`` (DataFrame with <name>, x0) and
    ``marginal`` (DataFrame with <name>_map, x0_map), either possibly empty, and optionally
    ``improper`` (the reason the posterior is improper: its marginal MAPs are not drawn and
    the legend says "improper" instead of |K^Stan|); ``name``: the parameter on the x axis
    (the paper's a).
    """
    plt = _plt()
    import seaborn as sns

    fig, axes = plt.subplots(1, 2, figsize=(9.0, 4.0), sharex=False, sharey=False)
    colours = sns.color_palette("deep", n_colors=max(len(panels), 1))
    for panel, colour in zip(panels, colours):
        j, m = panel["joint"], panel["marginal"]
        axes[0].scatter(
            j[name],
            j["x0"],
            s=6,
            alpha=0.5,
            color=colour,
            label=f"T={panel['T']} (|K^max|={len(j)})",
        )
        if panel.get("improper"):  # no marginal MAP of an improper posterior is drawn
            axes[1].scatter([], [], s=6, color=colour, label=f"T={panel['T']} (improper)")
            continue
        axes[1].scatter(
            m[f"{name}_map"],
            m["x0_map"],
            s=6,
            alpha=0.5,
            color=colour,
            label=f"T={panel['T']} (|K^Stan|={len(m)})",
        )
    for ax, title in zip(axes, ("joint MAP", "marginal MAP")):
        ax.axvline(omega_true, color="k", lw=0.8)
        ax.axhline(x0_true, color="k", lw=0.8)
        ax.set_xlabel(rf"$\hat {name}$" if len(name) == 1 else rf"$\hat\{name}$")
        ax.set_ylabel(r"$\hat x_0$")
        ax.set_title(title)
        ax.legend(fontsize=7, markerscale=2)
    fig.tight_layout()
    save_figure(fig, paths)
    plt.close(fig)


def figure_observability_ratios(
    frame: pandas.DataFrame, paths: Sequence[str | os.PathLike]
) -> None:
    """|K^max|/K and |K^Stan|/K for every scenario, ours beside the paper's, each bar with
    its exact binomial 95 % interval (``<fraction>_lo95`` / ``_hi95`` of the Section IV
    summary, :mod:`ssmobs.binomial`): at K = 40 about +-0.15, at the paper's K = 4000 about
    +-0.015.  A scenario whose posterior is improper (the summary's ``improper`` column) has
    no bar of ours for |K^Stan|/K but the word "improper"."""
    plt = _plt()
    n = len(frame)
    height = max(3.0, 0.35 * n + 1.5)
    fig, axes = plt.subplots(1, 2, figsize=(2 * height, height), sharey=True, squeeze=False)
    y = np.arange(n)
    bar = 0.38
    for ax, (title, col) in zip(
        axes[0], (("|K^max|/K", "K_max_frac"), ("|K^Stan|/K", "K_stan_frac"))
    ):
        for offset, (source, suffix, colour) in zip(
            (-bar / 2, bar / 2), (("ours", "", "tab:blue"), ("paper", "_paper", "tab:gray"))
        ):
            value = frame[f"{col}{suffix}"].to_numpy(dtype=float)
            lo = frame[f"{col}{suffix}_lo95"].to_numpy(dtype=float)
            hi = frame[f"{col}{suffix}_hi95"].to_numpy(dtype=float)
            err = np.vstack([value - lo, hi - value])
            ax.barh(
                y + offset,
                np.nan_to_num(value),
                height=bar,
                color=colour,
                label=source,
                xerr=np.where(np.isfinite(err), err, 0.0),
                error_kw={"lw": 0.8, "capsize": 2},
            )
        if col == "K_stan_frac" and "improper" in frame.columns:
            for row in np.flatnonzero(frame["improper"].fillna("").astype(bool).to_numpy()):
                ax.text(0.01, y[row] - bar / 2, "improper", va="center", fontsize=7)
        ax.set_xlim(0, 1.05)
        ax.set_title(f"{title} (95 % interval)")
        ax.set_xlabel("fraction")
    axes[0, 0].set_yticks(y, frame["scenario"].tolist())
    axes[0, 0].invert_yaxis()
    axes[0, 1].legend(title="source", fontsize=7, loc="lower right")
    fig.tight_layout()
    save_figure(fig, paths)
    plt.close(fig)


def figure_profile_posterior(
    a_values: np.ndarray,
    x0_values: np.ndarray,
    values: np.ndarray,
    a_true: float,
    x0_true: float,
    title: str,
    paths: Sequence[str | os.PathLike],
) -> None:
    """Figure 4 (Sec. IV.E): profile posterior pi(a, x0 | z~) = max over x_1..x_T."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    finite = values[np.isfinite(values)]
    vmin = np.quantile(finite, 0.05) if finite.size else None
    mesh = ax.pcolormesh(a_values, x0_values, values.T, shading="auto", cmap="viridis", vmin=vmin)
    ax.contour(a_values, x0_values, values.T, levels=12, colors="white", linewidths=0.5)
    fig.colorbar(mesh, ax=ax, label=r"$\pi(a, x_0 \mid \tilde z)$ (profile)")
    ax.plot([a_true], [x0_true], "r+", ms=10, mew=2)
    ax.set_xlabel("$a$")
    ax.set_ylabel("$x_0$")
    ax.set_title(title)
    fig.tight_layout()
    save_figure(fig, paths)
    plt.close(fig)


def figure_k_convergence(
    frame: pandas.DataFrame,
    chosen: pandas.DataFrame,
    title: str,
    paths: Sequence[str | os.PathLike],
) -> None:
    """Each component of V_{K_i} against K_i, one line per method and seed (Sec. IV.A).

    ``frame``: long table with columns K, method, seed, component, value;
    ``chosen``: method, seed, K_chosen (vertical markers).
    """
    plt = _plt()
    import seaborn as sns

    comps = list(dict.fromkeys(frame["component"]))
    ncol = min(4, len(comps))
    nrow = int(np.ceil(len(comps) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.2 * ncol, 2.6 * nrow), squeeze=False)
    frame = frame.assign(run=frame["method"] + " seed " + frame["seed"].astype(str))
    palette = dict(
        zip(
            sorted(frame["run"].unique()),
            sns.color_palette("tab10", n_colors=frame["run"].nunique()),
        )
    )
    for ax, comp in zip(axes.flat, comps):
        sub = frame[frame["component"] == comp]
        for run, g in sub.groupby("run", sort=True):
            ax.plot(g["K"], g["value"], marker="o", ms=3, lw=1, color=palette[run], label=run)
        ax.set_title(comp, fontsize=9)
        ax.set_xlabel("K")
    for ax in list(axes.flat)[len(comps) :]:
        ax.axis("off")
    for _, c in chosen.iterrows():
        if np.isfinite(c.get("K_chosen", np.nan)):
            run = f"{c['method']} seed {c['seed']}"
            for ax in list(axes.flat)[: len(comps)]:
                ax.axvline(c["K_chosen"], color=palette.get(run, "k"), ls=":", lw=0.8)
    axes.flat[0].legend(fontsize=6)
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, paths)
    plt.close(fig)


def figure_exact_vs_stan(
    stan: pandas.DataFrame,
    exact: pandas.DataFrame,
    names: Sequence[str],
    title: str,
    paths: Sequence[str | os.PathLike],
) -> None:
    """Stan + KDE marginal MAP against the exact one, trajectory by trajectory (issue 11).

    Top row: one scatter per component (exact on x, Stan + KDE on y, the diagonal); bottom
    row: histograms of the differences Stan - exact of the MAP and of the 5 %/95 % quantiles.
    ``stan`` and ``exact`` hold the same trajectories in the same order (converged in
    both).  The numbers of the comparison: :func:`ssmobs.reports.tables.exact_vs_stan_table`.
    """
    plt = _plt()
    fig, axes = plt.subplots(2, len(names), figsize=(3.2 * len(names), 6.0), squeeze=False)
    for i, name in enumerate(names):
        ex, st = exact[f"{name}_map"].to_numpy(float), stan[f"{name}_map"].to_numpy(float)
        ax = axes[0, i]
        ax.scatter(ex, st, s=6, alpha=0.6)
        if ex.size:
            lo, hi = np.nanmin([ex.min(), st.min()]), np.nanmax([ex.max(), st.max()])
            ax.plot([lo, hi], [lo, hi], color="k", lw=0.8)
        ax.set_xlabel(f"exact marginal MAP of {name}")
        ax.set_ylabel(f"Stan + KDE marginal MAP of {name}")
        ax.set_title(f"{title}: {name} (n = {len(ex)})", fontsize=8)
        ax = axes[1, i]
        for stat, label in (("map", "MAP"), ("q5", "5 %"), ("q95", "95 %")):
            d = stan[f"{name}_{stat}"].to_numpy(float) - exact[f"{name}_{stat}"].to_numpy(float)
            d = d[np.isfinite(d)]
            if d.size:
                ax.hist(d, bins=30, histtype="step", label=label)
        ax.axvline(0, color="k", lw=0.8)
        ax.set_xlabel(f"Stan + KDE - exact ({name})")
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, paths)
    plt.close(fig)
