"""Size budget of a run: estimated memory per job and number of jobs, checked before any job.

A config with, say, K = 10 000 000 and T = 1000 is valid in every key, but Snakemake would
spend minutes building a DAG of millions of jobs and the design stage would then ask NumPy
for tens of GiB.  :func:`problems` estimates, from the config alone and in microseconds,

* the memory of every job kind of every scenario: design disturbances (the (q x K) matrix
  and the optimiser's working set, Sec. III.A), design trajectories, joint MAP (Sec. III.B;
  the (K x |Theta|) results and the working set of one chunk), one Stan batch and the
  gathering of all records (Sec. III.C), the choice of K (Sec. IV.A) and Figure 4;
* the number of jobs of the run,

and lists every estimate above ``config["limits"]`` (``job_memory_gib``, ``jobs``), naming
the scenario, the estimate and the limit.

The coefficients are upper envelopes of peak NumPy memory measured with ``tracemalloc``
(2026-11-29) plus the interpreter and imported libraries (about 170 MiB resident, measured):
design optimisation 21-23 x the (q x K) matrix, random/antithetic sets 2-3 x the matrix plus
the (q x q) covariance, joint MAP about 6 x the (K x |Theta|) results plus one chunk's
working set (36-73 numbers per Theta component and trajectory, measured for the six models
at T = 4..300; we take 100), Figure 4 about 10 numbers per Theta component and grid point.
Each estimate is multiplied by :data:`MARGIN`.

A time budget besides: the CPU hours of the joint-MAP starts of the run (K trajectories x
n_starts starts per scenario and map cell, :func:`joint_map_cpu_seconds`), above
``limits.joint_map_cpu_hours``, stop it with the estimate and the rule (``n_starts:
1000000`` would run for years).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..models import MODELS, StateSpaceModel

GIB = 2**30
MIB = 2**20
F8 = 8  # bytes of a float64

#: resident memory of a job before it allocates arrays (Python, NumPy, SciPy, xarray, ...)
BASE_BYTES = 300 * MIB
#: block-wise pairwise evaluation of the LCD distance (BLOCK_SIZE^2 x quadrature nodes)
LCD_BLOCK_BYTES = 80 * MIB
#: safety factor on every estimate
MARGIN = 1.25
#: joint-MAP chunk rule of ssmobs.joint_map.driver._chunks (trajectories optimised together)
JOINT_MAP_CHUNK_WORK = 2e5
#: numbers of the joint-MAP working set per Theta component and trajectory of a chunk
#: (measured 36-73 for the six models, T = 4..300)
JOINT_MAP_PER_THETA = 100
#: jobs besides the per-scenario ones: tables, figures 2-4, observability figure, `all`
FIXED_JOBS = 7
#: CPU seconds of one joint-MAP start of one trajectory per Theta component, up to
#: |Theta| = JOINT_MAP_CPU_SQRT_FROM (above it the cost grows as |Theta|^1.5): about 2.5
#: times the largest measured (2026-12-07, process CPU of the multi-start's joint_map
#: calls): 0.017-0.41 ms with 40-100 trajectories (Same T = 50 to (Sep, d=1, p=2) T = 100,
#: |Theta| 52-303), up to 0.87 ms with 10 (the batch's fixed cost shared by fewer)
JOINT_MAP_CPU_S_PER_THETA = 2e-3
JOINT_MAP_CPU_SQRT_FROM = 200


@dataclass(frozen=True)
class JobEstimate:
    """Estimated peak memory (bytes) of one job kind of one scenario or k_selection entry."""

    owner: str  # "scenario 'x'" or "k_selection 'y'" or "figure2"
    job: str  # rule name
    bytes: float
    sizes: str  # the sizes that drive it, for the message


def _gib(b: float) -> str:
    return f"{b / GIB:.1f} GiB"


def disturbance_bytes(q: int, K: int, method: str) -> float:
    """Design disturbances (q x K): the optimiser's working set or a random set's copies."""
    matrix = F8 * q * K
    covariance = F8 * q * q  # whitening (doc Sec. 5): C, eigenvectors, W and a refinement
    per_matrix = 24 if method == "design" else 4
    return per_matrix * matrix + 4 * covariance + LCD_BLOCK_BYTES


def trajectories_bytes(q: int, K: int) -> float:
    """Design trajectories: the disturbance matrix read, x and z (K T (p + d) = q K numbers)
    and the copy written to NetCDF."""
    return 4 * F8 * q * K


def joint_map_bytes(model: StateSpaceModel, T: int, K: int, chunk_size: int = 0) -> float:
    """Joint MAP of K trajectories: results (K x |Theta|) and one chunk's working set."""
    n = model.n_theta(T)
    q = (model.obs_dim + model.state_dim) * T
    chunk = chunk_size or int(min(max(JOINT_MAP_CHUNK_WORK / n, 64), 2048))
    chunk = min(chunk, K)
    return 6 * F8 * K * n + JOINT_MAP_PER_THETA * F8 * chunk * n + 2 * F8 * q * K


def stan_batch_bytes(model: StateSpaceModel, T: int, K: int, stan: dict) -> float:
    """One Stan batch: the scenario's trajectories and one run's draws (with ArviZ copies)."""
    n = model.n_theta(T)
    q = (model.obs_dim + model.state_dim) * T
    draws = F8 * stan["chains"] * (stan["iter_sampling"] + stan["iter_warmup"]) * (n + 8)
    return 2 * F8 * q * K + 4 * draws


def gather_bytes(model: StateSpaceModel, T: int, K: int) -> float:
    """gather_nuts: the per-k table (3 |Theta| + 13 columns) read, concatenated and written."""
    n = model.n_theta(T)
    q = (model.obs_dim + model.state_dim) * T
    return 4 * F8 * K * (3 * n + 13) + 2 * F8 * q * K


def profile_posterior_bytes(model: StateSpaceModel, T: int, n_grid: int) -> float:
    """Figure 4: Newton's method over x_1..x_T batched over all n^2 grid points."""
    n = model.n_theta(T)
    return 10 * F8 * n_grid**2 * n


def estimates(config: dict) -> list[JobEstimate]:
    """Memory estimates of every job kind of the (validated) config."""
    out: list[JobEstimate] = []
    jm = config["joint_map"]
    stan = config["stan"]
    scenarios = {sc["name"]: sc for sc in config["scenarios"]}
    for sc in config["scenarios"]:
        model = MODELS[sc["model"]]
        T, K = sc["T"], sc["K"]
        q = (model.obs_dim + model.state_dim) * T
        who = f"scenario '{sc['name']}'"
        sizes = f"K = {K}, T = {T}, q = {q}"
        out.append(
            JobEstimate(
                who,
                "design_disturbances",
                disturbance_bytes(q, K, sc["method"]),
                sizes + f", {sc['method']}",
            )
        )
        out.append(JobEstimate(who, "design_trajectories", trajectories_bytes(q, K), sizes))
        if sc["joint_map"]:
            out.append(
                JobEstimate(
                    who,
                    "joint_map",
                    joint_map_bytes(model, T, K, jm["chunk_size"]),
                    sizes + f", |Theta| = {model.n_theta(T)}",
                )
            )
        if sc["stan"]:
            out.append(
                JobEstimate(
                    who,
                    "sample_nuts",
                    stan_batch_bytes(model, T, K, stan),
                    sizes + f", {stan['chains']} chains x "
                    f"{stan['iter_warmup'] + stan['iter_sampling']} iterations",
                )
            )
            out.append(
                JobEstimate(
                    who,
                    "gather_nuts",
                    gather_bytes(model, T, K),
                    sizes + f", |Theta| = {model.n_theta(T)}",
                )
            )
    for entry in config.get("observability_maps", []):
        model = MODELS[entry["base"]["model"]]
        T, K = max(entry["T"]), entry["K"]
        q = (model.obs_dim + model.state_dim) * T
        method = entry["base"].get("method", "design")
        out.append(
            JobEstimate(
                f"observability map '{entry['name']}'",
                "observability_map",
                max(
                    disturbance_bytes(q, K, method),
                    trajectories_bytes(q, K),
                    joint_map_bytes(model, T, K, jm["chunk_size"]),
                ),
                f"K = {K}, T = {T}, q = {q}, |Theta| = {model.n_theta(T)} (largest cell)",
            )
        )
    for ks in config["k_selection"]:
        sc = scenarios.get(ks["scenario"])
        if sc is None:
            continue
        model = MODELS[sc["model"]]
        T, K = sc["T"], max(ks["K_grid"])
        q = (model.obs_dim + model.state_dim) * T
        who = f"k_selection '{ks['name']}'"
        sizes = f"largest K_i = {K}, T = {T}, q = {q}"
        # one job per grid makes its sets and scores them, one K_i after the other
        out.append(
            JobEstimate(
                who,
                "k_selection_grid",
                max(
                    max(disturbance_bytes(q, K, method) for method in ks["methods"]),
                    trajectories_bytes(q, K) + joint_map_bytes(model, T, K, jm["chunk_size"]),
                ),
                sizes,
            )
        )
    f2 = config["figure2"]
    out.append(
        JobEstimate(
            "figure2",
            "design_disturbances",
            disturbance_bytes(2, f2["K"], "design"),
            f"K = {f2['K']}, q = 2",
        )
    )
    sc = scenarios.get(config["paper_outputs"]["figure4"] or "")  # the scenario of Figure 4
    if sc is not None:
        n_grid = config["figure4"]["n"]
        out.append(
            JobEstimate(
                f"scenario '{sc['name']}'",
                "figure_profile_posterior",
                profile_posterior_bytes(MODELS[sc["model"]], sc["T"], n_grid),
                f"figure4.n = {n_grid}",
            )
        )
    return [JobEstimate(e.owner, e.job, MARGIN * (BASE_BYTES + e.bytes), e.sizes) for e in out]


def job_counts(config: dict) -> dict[str, int]:
    """Number of jobs of the run, by what makes them (shared files counted once)."""

    counts: dict[str, int] = {}
    disturbances: set[tuple] = set()
    for sc in config["scenarios"]:
        model = MODELS[sc["model"]]
        q = (model.obs_dim + model.state_dim) * sc["T"]
        disturbances.add((q, sc["K"], sc["method"], sc["seed"]))
        n = 2 + int(sc["joint_map"])  # check_model (one per scenario), design_trajectories
        if sc["stan"]:  # check_model_stan, the batches and gather_nuts
            batch = sc.get("stan_batch_size") or config["stan"]["batch_size"]
            runs = math.ceil(sc["K"] / sc.get("stan_every", 1))
            n += 1 + math.ceil(runs / batch) + 1
        if sc.get("exact", True) and model.linear_in_states:  # the exact stage (issue 11)
            n += 1 + int(bool(sc["stan"]))  # exact_marginal, figure_exact_vs_stan
            exact_K = sc.get("exact_K") or sc["K"]
            if exact_K != sc["K"]:
                n += 1  # design_trajectories at the exact stage's K
                n += int(bool(sc["stan"]))  # exact_marginal at K too, for the figure
                disturbances.add((q, exact_K, sc["method"], sc["seed"]))
        counts[f"scenario '{sc['name']}'"] = n
    scenarios = {sc["name"]: sc for sc in config["scenarios"]}
    for ks in config["k_selection"]:
        sc = scenarios.get(ks["scenario"])
        if sc is None:
            continue
        sets = ks.get("sets") or ["nested"]
        runs = len(ks["methods"]) * len(ks["seeds"]) * len(sets)  # every seed of every method
        # one k_selection_grid job per (method, set variant, seed), which makes its own
        # sets, and select_k
        counts[f"k_selection '{ks['name']}'"] = runs + 1
    if config.get("observability_maps"):  # one job per map; its cells and sets in the job
        counts["observability maps"] = len(config["observability_maps"])
    counts["design disturbance sets"] = len(disturbances) + 1  # + Figure 2's
    counts["Stan programs, tables and figures"] = (
        len({sc["model"] for sc in config["scenarios"] if sc["stan"]}) + FIXED_JOBS
    )
    return counts


def joint_map_start_seconds(model: StateSpaceModel, T: int) -> float:
    """Estimated CPU seconds of one joint-MAP start of one trajectory (Sec. III.B; checks
    and ridge re-optimisation included): :data:`JOINT_MAP_CPU_S_PER_THETA` per Theta
    component, times sqrt(|Theta| / :data:`JOINT_MAP_CPU_SQRT_FROM`) above that size."""
    n = model.n_theta(T)
    return JOINT_MAP_CPU_S_PER_THETA * n * max(1.0, math.sqrt(n / JOINT_MAP_CPU_SQRT_FROM))


def joint_map_cpu_seconds(config: dict) -> dict[str, float]:
    """Estimated CPU seconds of the joint-MAP stage (all starts) by scenario and
    observability map: K x n_starts x :func:`joint_map_start_seconds` (the choice of K and
    Figure 4 use the paper's one start and are left out)."""
    block = config["joint_map"]["n_starts"]
    out: dict[str, float] = {}
    for sc in config["scenarios"]:
        if not sc["joint_map"]:
            continue
        starts = sc.get("joint_map_n_starts") or block
        model = MODELS[sc["model"]]
        out[f"scenario '{sc['name']}'"] = sc["K"] * starts * joint_map_start_seconds(model, sc["T"])
    for entry in config.get("observability_maps", []):
        model = MODELS[entry["base"]["model"]]
        starts = entry["base"].get("joint_map_n_starts") or block
        cells = len(entry["values"]) * sum(joint_map_start_seconds(model, T) for T in entry["T"])
        out[f"observability map '{entry['name']}'"] = entry["K"] * starts * cells
    return out


def time_problems(config: dict) -> list[str]:
    """One message when the joint-MAP starts of the run would take more than
    ``limits.joint_map_cpu_hours`` CPU hours (:func:`joint_map_cpu_seconds`)."""
    limit = config["limits"]["joint_map_cpu_hours"]
    seconds = joint_map_cpu_seconds(config)
    total = sum(seconds.values())
    if total <= 3600 * limit:
        return []
    largest = sorted(seconds.items(), key=lambda kv: -kv[1])[:3]
    detail = ", ".join(f"{who}: {s / 3600:.3g}" for who, s in largest)
    n_starts = config["joint_map"]["n_starts"]
    return [
        f"the joint-MAP starts of the run would take about {total / 3600:.3g} CPU hours "
        f"(largest: {detail}), more than limits.joint_map_cpu_hours = {limit}; the estimate "
        f"is K x n_starts x {1e3 * JOINT_MAP_CPU_S_PER_THETA:g} ms per component of Theta "
        f"(x sqrt(|Theta| / {JOINT_MAP_CPU_SQRT_FROM}) above {JOINT_MAP_CPU_SQRT_FROM}) per "
        f"scenario and map cell; reduce joint_map.n_starts (now {n_starts}), "
        f"joint_map_n_starts or K, or raise the limit (config/README.md, section 'limits')"
    ]


def problems(config: dict) -> list[str]:
    """One message per job kind above ``limits.job_memory_gib``, one if there are more
    than ``limits.jobs`` jobs and one if the joint-MAP starts exceed
    ``limits.joint_map_cpu_hours`` (:func:`time_problems`); empty when the run fits."""
    limits = config["limits"]
    mem_limit = limits["job_memory_gib"] * GIB
    out = []
    for e in estimates(config):
        if e.bytes > mem_limit:
            out.append(
                f"{e.owner}: a {e.job} job needs about {_gib(e.bytes)} of memory "
                f"({e.sizes}), more than limits.job_memory_gib = "
                f"{limits['job_memory_gib']} GiB; reduce the sizes or raise the limit "
                f"(config/README.md, section 'limits')"
            )
    counts = job_counts(config)
    total = sum(counts.values())
    if total > limits["jobs"]:
        largest = sorted(counts.items(), key=lambda kv: -kv[1])[:3]
        detail = ", ".join(f"{who}: {n}" for who, n in largest)
        out.append(
            f"the run would have about {total} jobs, more than limits.jobs = "
            f"{limits['jobs']} (largest: {detail}); reduce K, raise stan.batch_size "
            f"(now {config['stan']['batch_size']}) or raise limits.jobs "
            f"(config/README.md, section 'limits')"
        )
    return out + time_problems(config)
