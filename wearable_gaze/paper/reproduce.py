"""Reproduce the paper's simulation (Table 1, Fig. 11, Fig. 13) and its single-pair depth plot.

Every number is measured here, from seeded trials; the paper's own columns are printed beside
ours for comparison, not as targets (see ../shared/paper/NOTES.md: its "proposed" errors lie far
below the Cramér-Rao bound of its own protocol).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator import closest_point_two_lines, cramer_rao_bound, make_estimator, run_estimator

from ..progress import Progress
from ..sim.protocol import PAPER_DEPTHS_MM, PAPER_TABLE1, Protocol, simulate_lines

log = logging.getLogger(__name__)

TABLE_METHODS = ("lse", "paper", "voxel", "ml")


@dataclass
class MethodStats:
    """Errors of one method at one depth over trials (mm)."""

    estimates_mm: list = field(default_factory=list)
    failures: int = 0

    def summary(self, truth) -> dict:
        e = np.array(self.estimates_mm).reshape(-1, 3)
        if len(e) == 0:
            return {"mean_mm": None, "rmse_mm": None, "median_error_mm": None, "failures": self.failures}
        err = np.linalg.norm(e - truth, axis=1)
        return {"mean_mm": e.mean(axis=0).tolist(), "rmse_mm": float(np.sqrt(np.mean(err**2))),
                "median_error_mm": float(np.median(err)), "failures": self.failures, "n": len(e)}


@dataclass
class Table1Result:
    """Per depth: each method's summary and the Cramér-Rao bound."""

    trials: int
    seed: int
    rows: list

    def format(self) -> str:
        """The table as text: the paper's two columns, then ours, then the bound."""
        head = (f"{'Z mm':>6} | {'paper proposed':>16} {'err':>5} | {'paper LSE':>16} {'err':>5} |"
                + "".join(f" {m + ' mean z':>13} {'RMSE':>6} {'med':>6} |" for m in TABLE_METHODS)
                + f" {'CRB':>6} {'CRB z':>6}")
        lines = [f"Paper Table 1 protocol, {self.trials} trials per depth, seed {self.seed} (mm; "
                 f"RMSE and median of the 3D error; CRB = sqrt(trace) of the Cramér-Rao bound)", head,
                 "-" * len(head)]
        for r in self.rows:
            z = int(r["depth_mm"])
            pp, pe, lp, le = PAPER_TABLE1.get(z, ((np.nan,) * 3, np.nan, (np.nan,) * 3, np.nan))
            s = (f"{z:>6} | {str(tuple(pp)):>16} {pe:>5} | {str(tuple(lp)):>16} {le:>5} |")
            for m in TABLE_METHODS:
                st = r["methods"][m]
                if st["mean_mm"] is None:
                    s += f" {'failed':>13} {'':>6} {'':>6} |"
                else:
                    s += f" {st['mean_mm'][2]:>13.0f} {st['rmse_mm']:>6.0f} {st['median_error_mm']:>6.0f} |"
            s += f" {r['crb_mm']:>6.1f} {r['crb_z_mm']:>6.1f}"
            lines.append(s)
        lines.append("")
        lines.append("RMSE / CRB: " + "   ".join(
            f"{int(r['depth_mm'])}: " + ", ".join(
                f"{m} {r['methods'][m]['rmse_mm'] / r['crb_mm']:.2f}" for m in ("ml", "voxel")
                if r["methods"][m]["rmse_mm"] is not None) for r in self.rows))
        lines.append(f"(with {self.trials} trials per depth an RMSE is known to about "
                     f"+-{100 / np.sqrt(2 * self.trials):.0f} %; run more trials to tighten it)")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"trials": self.trials, "seed": self.seed, "rows": self.rows}


def run_table1(trials: int = 20, seed: int = 0, depths_mm=PAPER_DEPTHS_MM, protocol: Protocol = Protocol(),
               methods=TABLE_METHODS, progress: Progress | None = None) -> Table1Result:
    """Run the paper's protocol ``trials`` times per depth with every method.

    Args:
        trials: trials per depth.
        seed: seed of the generator (same seed, same numbers).
        depths_mm: target depths Z, mm; the target is (0, 0, Z).
        protocol: head path and noise.
        methods: estimator names.
        progress: called as ``progress(done, total)`` after each trial.
    """
    if trials < 1:
        raise ValueError(f"trials must be at least 1, got {trials}")
    rng = np.random.default_rng(seed)
    rows = []
    total = trials * len(depths_mm)
    done = 0
    for z in depths_mm:
        truth = np.array([0.0, 0.0, float(z)])
        stats = {m: MethodStats() for m in methods}
        for _ in range(trials):
            samples = simulate_lines(truth, rng, protocol)
            for m in methods:
                _, r = run_estimator(samples, m, protocol.sigma_deg)
                if r.position_mm is None:
                    stats[m].failures += 1
                else:
                    stats[m].estimates_mm.append(r.position_mm)
            done += 1
            if progress:
                progress(done, total)
        origins = samples.lines().origins_mm
        crb = cramer_rao_bound(origins, truth, protocol.sigma_deg)
        rows.append({"depth_mm": float(z), "crb_mm": float(np.sqrt(np.trace(crb))),
                     "crb_z_mm": float(np.sqrt(crb[2, 2])),
                     "methods": {m: stats[m].summary(truth) for m in methods}})
    return Table1Result(trials, seed, rows)


def convergence(depth_mm: float, seed: int, protocol: Protocol = Protocol(), methods=TABLE_METHODS) -> dict:
    """Estimated depth (mm) after each observation, one trial, per streaming method (Fig. 13)."""
    rng = np.random.default_rng(seed)
    truth = np.array([0.0, 0.0, float(depth_mm)])
    samples = simulate_lines(truth, rng, protocol)
    out = {}
    for m in methods:
        est = make_estimator(m, protocol.sigma_deg)
        z = []
        for i in range(len(samples)):
            r = est.update(samples.sample(i))
            z.append(r.position_mm[2] if r.position_mm is not None else np.nan)
        out[m] = np.array(z)
    return out


def plot_fig11(out_path, seed: int = 0, protocol: Protocol = Protocol(), depths_mm=(1000.0, 3000.0, 5000.0)):
    """Density slices at y = 0 after all 200 samples (like the paper's Fig. 11): the paper's
    voxel space (top) and our Bayesian log-likelihood (bottom, evaluated from the kept lines)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(depths_mm), figsize=(4.2 * len(depths_mm), 8), squeeze=False)
    for col, z in enumerate(depths_mm):
        rng = np.random.default_rng(seed + col)
        truth = np.array([0.0, 0.0, z])
        samples = simulate_lines(truth, rng, protocol)
        paper = make_estimator("paper", protocol.sigma_deg)
        paper.add(samples)
        g = paper.grid
        jy = int(np.argmin(np.abs(g.offsets[1] + g.center_mm[1])))
        sl = g.values[:, jy, :]
        ext = [g.center_mm[2] + g.offsets[2][0], g.center_mm[2] + g.offsets[2][-1],
               g.center_mm[0] + g.offsets[0][0], g.center_mm[0] + g.offsets[0][-1]]
        ax = axes[0, col]
        ax.set_facecolor("black")   # outside the paper's voxel space: no density
        ax.imshow(sl, origin="lower", extent=ext, aspect="auto", cmap="magma")
        ax.plot([z], [0], "c+", ms=14, mew=2, label="truth")
        pz = paper.estimate().position_mm
        ax.plot([pz[2]], [pz[0]], "wx", ms=10, mew=2, label="estimate")
        ax.set_title(f"paper method, Z = {z / 1000:.0f} m")
        ax.set_xlabel("z (mm)")
        ax.set_ylabel("x (mm)")
        ax.legend(loc="upper right", fontsize=8)

        vox, r = run_estimator(samples, "voxel", protocol.sigma_deg)
        sz = max(4 * np.sqrt(r.covariance_mm2[2, 2]), 50.0)
        sx = max(4 * np.sqrt(r.covariance_mm2[0, 0]), 5.0)
        zz, xx = np.meshgrid(np.linspace(r.position_mm[2] - sz, r.position_mm[2] + sz, 160),
                             np.linspace(r.position_mm[0] - sx, r.position_mm[0] + sx, 120))
        pts = np.column_stack([xx.ravel(), np.zeros(xx.size), zz.ravel()])
        ld = vox.log_density_at(pts).reshape(xx.shape)
        ax = axes[1, col]
        ax.imshow(np.exp(ld - ld.max()), origin="lower", aspect="auto", cmap="magma",
                  extent=[zz.min(), zz.max(), xx.min(), xx.max()])
        ax.plot([z], [0], "c+", ms=14, mew=2, label="truth")
        ax.plot([r.position_mm[2]], [r.position_mm[0]], "wx", ms=10, mew=2, label="estimate")
        ax.set_title(f"voxel (Bayesian) posterior, Z = {z / 1000:.0f} m")
        ax.set_xlabel("z (mm)")
        ax.set_ylabel("x (mm)")
        ax.legend(loc="upper right", fontsize=8)
    fig.suptitle("Density in the plane y = 0 after 200 binocular samples (cf. paper Fig. 11)")
    fig.tight_layout()
    _save(fig, out_path)


def plot_fig13(out_path, seed: int = 0, protocol: Protocol = Protocol(), depths_mm=PAPER_DEPTHS_MM):
    """Estimated depth against the number of observations (like the paper's Fig. 13)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(TABLE_METHODS), figsize=(4.2 * len(TABLE_METHODS), 4.2), sharey=True)
    colors = plt.cm.viridis(np.linspace(0, 0.9, len(depths_mm)))
    for i, z in enumerate(depths_mm):
        conv = convergence(z, seed + i, protocol)
        for ax, m in zip(axes, TABLE_METHODS, strict=True):
            ax.plot(np.arange(1, len(conv[m]) + 1), conv[m], color=colors[i], label=f"Z = {z / 1000:.0f} m")
            ax.axhline(z, color=colors[i], ls=":", lw=1)
    for ax, m in zip(axes, TABLE_METHODS, strict=True):
        ax.set_title(m)
        ax.set_xlabel("binocular observations")
        ax.set_ylim(0, 1.3 * max(depths_mm))
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("estimated depth z (mm)")
    axes[-1].legend(fontsize=8)
    fig.suptitle("Estimated depth against the number of observations (cf. paper Fig. 13); dotted: truth")
    fig.tight_layout()
    _save(fig, out_path)


@dataclass
class Figure5Result:
    """Single-pair triangulated depths over time for each target distance."""

    t_s: np.ndarray
    depths_mm: dict

    def format(self) -> str:
        lines = ["Depth from single binocular pairs (eq. 12 per sample, head still, 1 deg noise; "
                 "quartiles count diverging pairs as infinitely far):",
                 f"{'true mm':>8} {'median':>8} {'IQR':>8} {'diverging':>10}"]
        for z, d in self.depths_mm.items():
            # a diverging pair is a depth beyond infinity, not a missing one: it sorts last
            q1, q2, q3 = np.percentile(np.where(np.isfinite(d), d, np.inf), [25, 50, 75], method="nearest")
            lines.append(f"{z:>8.0f} {q2:>8.0f} {q3 - q1:>8.0f} {np.mean(~np.isfinite(d)):>10.0%}")
        lines.append("Vertical noise makes the two lines skew; their closest approach then lies nearer than "
                     "the target (z = b v / (v^2 + dv^2)), so single pairs read short as well as noisy.")
        return "\n".join(lines)


def run_figure5(seed: int = 0, distances_mm=(1200.0, 1600.0, 2400.0, 3300.0), duration_s: float = 10.0,
                protocol: Protocol = Protocol()) -> Figure5Result:
    """Depth of the closest point of each binocular pair over time, head still, target at each
    distance (the paper's real-device situation of section 6.2, simulated). Diverging or parallel
    pairs give no depth (NaN in the result, counted as "diverging")."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * protocol.rate_hz)
    heads = np.zeros((n, 3))
    out = {}
    for z in distances_mm:
        s = simulate_lines([0.0, 0.0, z], rng, protocol, heads_mm=heads)
        pair = closest_point_two_lines(s.left_origin_mm, s.left_direction, s.right_origin_mm, s.right_direction)
        depth = np.where(pair.status == 0, pair.point_mm[:, 2], np.nan)
        out[float(z)] = depth
    return Figure5Result(np.arange(n) / protocol.rate_hz, out)


def plot_figure5(result: Figure5Result, out_path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    colors = plt.cm.plasma(np.linspace(0, 0.85, len(result.depths_mm)))
    for c, (z, d) in zip(colors, result.depths_mm.items(), strict=True):
        ax.plot(result.t_s, d, ".", ms=3, color=c, label=f"{z / 1000:.1f} m")
        ax.axhline(z, color=c, lw=1)
    ax.set_ylim(0, 8000)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("depth from one binocular pair (mm)")
    ax.set_title("Single-pair triangulation (eq. 12): reliable near 1.2 m, not beyond 3 m (cf. paper Fig. 5)")
    ax.legend(title="target")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _save(fig, out_path)


def _save(fig, out_path):
    import matplotlib.pyplot as plt

    from ..formats.atomic import atomic_path

    with atomic_path(out_path) as tmp:
        fig.savefig(tmp, dpi=110, format=Path(out_path).suffix.lstrip(".") or "png")
    plt.close(fig)


def reproduce_table1(out_dir, trials: int = 20, seed: int = 0,
                     progress: Progress | None = None) -> tuple[Table1Result, list[Path]]:
    """Run Table 1, write ``table1.txt``, ``table1.json``, ``fig11_density_slices.png`` and
    ``fig13_convergence.png`` into ``out_dir``; return the result and the written paths."""
    import json

    from ..formats.atomic import write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = run_table1(trials, seed, progress=progress)
    paths = [out / "table1.txt", out / "table1.json", out / "fig11_density_slices.png", out / "fig13_convergence.png"]
    write_text(paths[0], result.format() + "\n")
    write_text(paths[1], json.dumps(result.to_dict(), indent=2) + "\n")
    plot_fig11(paths[2], seed)
    plot_fig13(paths[3], seed)
    return result, paths


def reproduce_figure5(out_dir, seed: int = 0) -> tuple[Figure5Result, list[Path]]:
    """Run the single-pair experiment and write ``figure5_single_pairs.png`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = run_figure5(seed)
    path = out / "figure5_single_pairs.png"
    plot_figure5(result, path)
    return result, [path]
