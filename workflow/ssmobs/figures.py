"""Paper figures (seaborn/matplotlib); each function writes PDF and PNG atomically."""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from . import io


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import seaborn as sns

    sns.set_theme(style="whitegrid", context="paper")
    return plt


def save_figure(fig, paths: Sequence[str | os.PathLike]) -> None:
    """Save one figure to several formats atomically (format from each path's suffix).

    PDF metadata dates are removed so that reruns give identical bytes.
    """
    for path in paths:
        path = os.fspath(path)
        ext = os.path.splitext(path)[1].lstrip(".")
        meta = {"CreationDate": None} if ext == "pdf" else {"Software": None}
        with io.atomic_path(path) as tmp:
            fig.savefig(tmp, format=ext, dpi=150, bbox_inches="tight", metadata=meta)


def _gauss_contours(ax, mean: np.ndarray, cov: np.ndarray, span: float = 3.2, levels: int = 6):
    sd = np.sqrt(np.diag(cov))
    gx = np.linspace(mean[0] - span * sd[0], mean[0] + span * sd[0], 200)
    gy = np.linspace(mean[1] - span * sd[1], mean[1] + span * sd[1], 200)
    X, Y = np.meshgrid(gx, gy)
    d = np.stack([X - mean[0], Y - mean[1]], axis=-1)
    inv = np.linalg.inv(cov)
    dens = np.exp(-0.5 * np.einsum("...i,ij,...j->...", d, inv, d))
    dens /= 2 * np.pi * np.sqrt(np.linalg.det(cov))
    ax.contour(X, Y, dens, levels=levels, cmap="Blues", linewidths=0.9)


def figure_design_points(disturbances: np.ndarray, a: float, x0: float,
                         paths: Sequence[str | os.PathLike]) -> None:
    """Figure 2 (Sec. III.A, Example 5): design disturbances (eta_1, eps_1) over N(0, I_2)
    and the design values (x~_1, z~_1) of model Same over the density of (X_1, Z_1).
    """
    from .models import get_model

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
