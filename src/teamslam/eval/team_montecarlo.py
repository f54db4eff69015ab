"""Monte Carlo consistency of the 3D team filter: linearisation × team mode.

``N`` noise realisations of one simulated team (the Lissajous arena, or the long non-repeating
route), each run through every linearisation policy and
every mode (``separate``, ``consensus``, ``hybrid``, ``increments``, ``centralised``) over a
process pool. Per filter and mode: pose ANEES (per frame, mean over runs, divided by 6) with its
two-sided 95 % χ² band, object ANEES with its band, position and heading RMSE, the median run
and the runs above the band, and the per-frame curves. Every filter and mode sees the same
realisations, so ``paired_rmse`` compares them run by run: the mean per-run RMSE difference with
its 95 % Student-t interval, relative difference, and how many runs each won.

Run ``k`` draws its noise from ``(seed, k)`` whatever process or cluster worker runs it, so a
study is the same, bit for bit, on one process, ``N`` processes or a Dask cluster
(``scheduler``); each run is kept in ``out/runs`` as it finishes, and ``resume`` runs only the
ones missing there (:mod:`teamslam.eval.studies`).
"""

from __future__ import annotations

import functools
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from teamslam._optional import require
from teamslam.eval.studies import RunStore
from teamslam.gaussian import chi2_band
from teamslam.geometry import se3
from teamslam.parallel import run_parallel

__all__ = [
    "MODES",
    "RUNS_DIR",
    "MonteCarloSpec",
    "paired_difference",
    "plot",
    "run_montecarlo",
    "study",
    "summarise",
    "table",
    "write_montecarlo",
]

MODES = ("separate", "consensus", "hybrid", "increments", "centralised")
GRAPHS = ("complete", "ring", "random")
ROUTES = ("lissajous", "long")
# the team setting each consensus mode turns on
_MODE_SETTINGS = {
    "consensus": {},
    "hybrid": {"consensus.rule": "hybrid"},
    "increments": {"consensus.rule": "increments"},
}
FILTERS = ("std", "fej", "ideal", "oc")
#: The folder of ``out`` each run is kept in as it finishes (one ``.npz`` per run).
RUNS_DIR = "runs"


@dataclass(frozen=True)
class MonteCarloSpec:
    """What to simulate and run.

    Attributes
    ----------
    robots, steps, runs
        Team size, motion steps per robot, noise realisations.
    filters
        Linearisation policies (``std``, ``fej``, ``ideal``, ``oc``).
    modes
        Team modes (``separate``, ``consensus``, ``hybrid``, ``increments``, ``centralised``).
    graph
        Communication graph of the consensus modes: ``complete``, ``ring`` or ``random`` (a
        connected random geometric graph drawn from ``seed``, the same in every run).
    loss
        Per-frame probability that a link is down (consensus modes; run ``k`` draws its link
        losses from seed ``k``).
    objects_only
        Ignore geometric features.
    seed
        Seed of the team (paths and map); run ``k`` draws its noise from ``(seed, k)``.
    window
        MSCKF window size.
    settings
        Further filter settings for every run (``(name, value)`` pairs, as ``--set`` gives).
    route
        ``lissajous`` (:func:`~teamslam.sim.lissajous_team`) or ``long``
        (:func:`~teamslam.sim.long_route_team`: robots side by side on a route that never comes
        back, ``steps`` metres); ``seed`` draws the route and its map, the same in every run.
    """

    robots: int = 5
    steps: int = 200
    runs: int = 20
    filters: tuple[str, ...] = ("std", "fej", "ideal")
    modes: tuple[str, ...] = ("separate", "consensus", "centralised")
    objects_only: bool = False
    seed: int = 0
    window: int = 10
    settings: tuple[tuple[str, object], ...] = ()
    graph: str = "complete"
    loss: float = 0.0
    route: str = "lissajous"

    def __post_init__(self) -> None:
        from teamslam.errors import InputError

        if self.robots < 1 or self.steps < 1 or self.runs < 1 or self.window < 2:
            raise InputError("robots, steps and runs must be positive and the window ≥ 2")
        for f in self.filters:
            if f not in FILTERS:
                raise InputError(f"unknown filter {f!r}; choose from {', '.join(FILTERS)}")
        for m in self.modes:
            if m not in MODES:
                raise InputError(f"unknown mode {m!r}; choose from {', '.join(MODES)}")
        if not self.filters or not self.modes:
            raise InputError("give at least one filter and one mode")
        if self.graph not in GRAPHS:
            raise InputError(f"unknown graph {self.graph!r}; choose from {', '.join(GRAPHS)}")
        if not 0 <= self.loss < 1:
            raise InputError(f"link loss must lie in [0, 1), not {self.loss}")
        if self.route not in ROUTES:
            raise InputError(f"unknown route {self.route!r}; choose from {', '.join(ROUTES)}")

    def communication_graph(self):
        """The consensus modes' communication graph."""
        from teamslam.graph import make

        return make(self.graph, self.robots, seed=self.seed)

    def team(self, run: int):
        """The simulated team of run ``run``."""
        from teamslam.sim import lissajous_team, long_route_team

        make = long_route_team if self.route == "long" else lissajous_team
        return make(self.robots, self.steps, seed=self.seed, noise_seed=run)


def _heading_error(estimated: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Rotation angle of ``R_estᵀ R_true`` per frame."""
    rel = np.swapaxes(estimated[..., :3, :3], -1, -2) @ truth[..., :3, :3]
    cos = np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return np.arccos(cos)


def one_run(run: int, spec: MonteCarloSpec) -> dict:
    """Every filter and mode on realisation ``run``: per-frame errors and NEES."""
    from teamslam.eval.metrics import object_nees
    from teamslam.msckf import config_for, run_team
    from teamslam.msckf.centralised import run_centralised

    team = spec.team(run)
    graph = spec.communication_graph()
    truth = np.stack([r.T_world_body for r in team.robots])  # (R, T + 1, 4, 4)
    out: dict = {}
    for filt in spec.filters:
        settings = {
            "filter.window": spec.window,
            "filter.use_geometric_features": not spec.objects_only,
            **dict(spec.settings),
            "filter.linearization": filt,
        }
        config = config_for(team, settings)
        for mode in spec.modes:
            if mode == "centralised":
                result = run_centralised(team, config, progress=False)
            elif mode == "separate":
                result = run_team(team, config, consensus=False, progress=False)
            else:
                result = run_team(
                    team,
                    config.with_(_MODE_SETTINGS[mode]),
                    graph=graph,
                    consensus=True,
                    loss=spec.loss,
                    seed=run,
                    progress=False,
                )
            poses = np.stack(result.poses)
            covs = np.stack(result.pose_covs)
            eps = se3.log(se3.inverse(poses) @ truth)
            nees = np.einsum("rti,rti->rt", eps, np.linalg.solve(covs, eps[..., None])[..., 0])
            out[f"{filt}/{mode}"] = {
                "nees_pose": nees / 6.0,
                "position_error": np.linalg.norm(poses[..., :3, 3] - truth[..., :3, 3], axis=-1),
                "heading_error": _heading_error(poses, truth),
                "nees_object": object_nees(team, result),
            }
    return out


def summarise(spec: MonteCarloSpec, runs: list[dict]) -> dict:
    """The JSON of a study from the per-run results (see the module docstring)."""
    n = len(runs)
    band = chi2_band(6, n)
    band_object = chi2_band(3, n)
    results: dict = {}
    for filt in spec.filters:
        results[filt] = {}
        for mode in spec.modes:
            key = f"{filt}/{mode}"
            nees = np.stack([r[key]["nees_pose"][:, 1:] for r in runs])  # (N, R, T)
            pos = np.stack([r[key]["position_error"][:, 1:] for r in runs])
            head = np.stack([r[key]["heading_error"][:, 1:] for r in runs])
            objects = np.concatenate([r[key]["nees_object"] for r in runs])
            per_run = nees.mean(axis=(1, 2))
            order = np.argsort(per_run)
            median = int(order[(n - 1) // 2])
            results[filt][mode] = {
                "anees_pose": float(nees.mean()),
                "anees_object": float(objects.mean()) if objects.size else float("nan"),
                "band": list(band),
                "band_object": list(band_object),
                "position_rmse_m": float(np.sqrt(np.mean(pos**2))),
                "heading_rmse_rad": float(np.sqrt(np.mean(head**2))),
                "median_run": {"run": median, "anees_pose": float(per_run[median])},
                "runs_above_band": int(np.sum(per_run > band[1])),
                "frames_inside_band": float(
                    np.mean((nees.mean(axis=0) >= band[0]) & (nees.mean(axis=0) <= band[1]))
                ),
                "anees_pose_per_frame": nees.mean(axis=(0, 1)).tolist(),
                "position_rmse_per_frame_m": np.sqrt(np.mean(pos**2, axis=(0, 1))).tolist(),
                "position_rmse_per_run_m": np.sqrt(np.mean(pos**2, axis=(1, 2))).tolist(),
            }
    paired: dict = {}
    if "std" in results:
        for filt in results:
            if filt == "std":
                continue
            paired[f"{filt}-std"] = {
                mode: paired_difference(
                    results[filt][mode]["position_rmse_per_run_m"],
                    results["std"][mode]["position_rmse_per_run_m"],
                )
                for mode in spec.modes
            }
    # each averaging rule against the paper's average, filter by filter, run by run
    if "consensus" in spec.modes:
        for mode in ("hybrid", "increments"):
            if mode in spec.modes:
                paired[f"{mode}-consensus"] = {
                    filt: paired_difference(
                        results[filt][mode]["position_rmse_per_run_m"],
                        results[filt]["consensus"]["position_rmse_per_run_m"],
                    )
                    for filt in spec.filters
                }
    return {**asdict(spec), "results": results, "paired_rmse": paired}


def paired_difference(
    values: list[float] | np.ndarray, reference: list[float] | np.ndarray, probability: float = 0.95
) -> dict:
    """Mean of ``values − reference`` over paired runs, with its Student-t confidence interval.

    Returns ``mean_difference_m``, ``interval_m`` (``[low, high]``, NaN with fewer than two
    runs), ``relative`` (the mean difference over the reference's mean) and ``runs_lower``
    (runs in which ``values`` is below ``reference``).
    """
    values = np.asarray(values, dtype=float)
    reference = np.asarray(reference, dtype=float)
    if values.shape != reference.shape or values.ndim != 1 or values.size == 0:
        raise ValueError(f"paired runs of different shapes {values.shape} and {reference.shape}")
    difference = values - reference
    n = difference.size
    mean = float(difference.mean())
    if n > 1:
        half = stats.t.ppf(0.5 + probability / 2, n - 1) * difference.std(ddof=1) / np.sqrt(n)
    else:
        half = float("nan")
    return {
        "mean_difference_m": mean,
        "interval_m": [mean - float(half), mean + float(half)],
        "relative": mean / float(reference.mean()),
        "runs_lower": int(np.sum(difference < 0)),
    }


def study(spec: MonteCarloSpec) -> dict:
    """What every run of ``spec`` depends on (its :class:`~teamslam.eval.studies.RunStore`
    identity): the spec but the number of runs, and teamslam's version."""
    from teamslam._version import __version__

    return {**{k: v for k, v in asdict(spec).items() if k != "runs"}, "teamslam": __version__}


def run_montecarlo(
    spec: MonteCarloSpec,
    workers: int | None = None,
    progress: bool | None = None,
    scheduler: str | None = None,
    store: RunStore | None = None,
) -> dict:
    """Run the study in parallel and summarise it.

    Parameters
    ----------
    workers, progress
        Processes and progress bar (:func:`~teamslam.parallel.run_parallel`).
    scheduler
        The address of a Dask scheduler: each run is a task there (the ``cluster`` extra).
    store
        Keeps each run as it finishes; the runs it holds already (``resume``) are read back,
        not run.
    """
    job = functools.partial(one_run, spec=spec)
    runs: dict[int, dict] = {}
    if store is not None:
        runs = {k: store.load(k) for k in range(spec.runs) if k in store}
    missing = [k for k in range(spec.runs) if k not in runs]
    save = None if store is None else store.save
    results = run_parallel(job, missing, workers, progress, "Monte Carlo runs", scheduler, save)
    runs.update(zip(missing, results, strict=True))
    return summarise(spec, [runs[k] for k in range(spec.runs)])


def write_montecarlo(
    spec: MonteCarloSpec,
    out: Path,
    workers: int | None = None,
    progress: bool | None = None,
    scheduler: str | None = None,
    resume: bool = False,
) -> tuple[dict, list[Path], RunStore]:
    """Run the study (:func:`run_montecarlo`, with its ``wall_seconds``), each run kept in
    ``out/runs`` as it finishes (:class:`~teamslam.eval.studies.RunStore`; with ``resume`` the
    runs kept there are not run again), and write ``montecarlo.json`` and the figures
    (:func:`plot`) into ``out``; the summary, the figures' paths and the store (how many runs
    it read back and wrote).

    Raises
    ------
    InputError
        ``resume`` and ``out/runs`` holds runs of another study; no Dask scheduler at
        ``scheduler``, or the ``cluster`` extra is missing.
    OutputError
        Something cannot be written (named).
    """
    import time

    from teamslam.eval.outputs import writing

    if scheduler is not None:  # before anything is written
        require("distributed", "cluster", "running on a Dask cluster")
    begin = time.perf_counter()
    store = RunStore(Path(out) / RUNS_DIR, study(spec), resume)
    summary = run_montecarlo(spec, workers, progress, scheduler, store)
    summary["wall_seconds"] = time.perf_counter() - begin
    out = Path(out)
    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
        (out / "montecarlo.json").write_text(json.dumps(summary, indent=2))
        return summary, plot(summary, out), store


def table(summary: dict) -> str:
    """Plain-text table of a summary."""
    lines = [
        f"{summary['runs']} runs, {summary['robots']} robots, {summary['steps']} steps"
        f"{' on the long route' if summary.get('route') == 'long' else ''}, "
        f"{'objects only' if summary['objects_only'] else 'objects + geometric features'}; "
        "pose 95% band {:.2f}–{:.2f}, object band {:.2f}–{:.2f}".format(
            *next(iter(next(iter(summary["results"].values())).values()))["band"],
            *next(iter(next(iter(summary["results"].values())).values()))["band_object"],
        ),
        f"{'filter':<7}{'mode':<13}{'ANEES pose':>11}{'ANEES obj':>11}{'pos RMSE m':>12}"
        f"{'head RMSE':>11}{'median run':>11}{'runs above':>11}",
    ]
    for filt, modes in summary["results"].items():
        for mode, r in modes.items():
            lines.append(
                f"{filt:<7}{mode:<13}{r['anees_pose']:>11.2f}{r['anees_object']:>11.2f}"
                f"{r['position_rmse_m']:>12.3f}{r['heading_rmse_rad']:>11.4f}"
                f"{r['median_run']['anees_pose']:>11.2f}{r['runs_above_band']:>11d}"
            )
    for pair, modes in summary.get("paired_rmse", {}).items():
        lines.append(f"per-run position RMSE, {pair.replace('-', ' − ')} (95% interval):")
        for mode, p in modes.items():  # a mode, or a filter for the averaging rules
            low, high = p["interval_m"]
            lines.append(
                f"  {mode:<12}{p['mean_difference_m']:+.4f} m [{low:+.4f}, {high:+.4f}] "
                f"({100 * p['relative']:+.1f}%), lower in {p['runs_lower']} of "
                f"{summary['runs']} runs"
            )
    return "\n".join(lines)


def plot(summary: dict, out: Path) -> list[Path]:
    """``nees.png`` and ``rmse.png``: per-frame ANEES (with the band) and position RMSE."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    modes = list(next(iter(summary["results"].values())))
    written = []
    for name, key, label in (
        ("nees.png", "anees_pose_per_frame", "pose ANEES / 6"),
        ("rmse.png", "position_rmse_per_frame_m", "position RMSE [m]"),
    ):
        fig, axes = plt.subplots(1, len(modes), figsize=(4.5 * len(modes), 3.5), squeeze=False)
        for ax, mode in zip(axes[0], modes, strict=True):
            for filt, by_mode in summary["results"].items():
                ax.plot(by_mode[mode][key], label=filt, lw=1)
            if key == "anees_pose_per_frame":
                lo, hi = by_mode[mode]["band"]
                ax.axhspan(lo, hi, color="0.85", zorder=0, label="95% band")
                ax.set_yscale("log")
            ax.set_title(mode)
            ax.set_xlabel("frame")
            ax.set_ylabel(label)
            ax.legend(fontsize=7)
        fig.tight_layout()
        path = out / name
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written
