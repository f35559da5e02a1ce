"""Monte-Carlo robustness campaigns: N seeded, randomised runs of a task (issue "Robustness").

The paper closes by calling for "a systematic sensitivity and robustness analysis"; a campaign is that
analysis. Run ``i`` of a campaign draws every varied parameter from ``np.random.default_rng([seed, i])``
(in the order of the parameter names, then the derived draws: simulator seed, rotor-error seed, event
times), so any run can be repeated alone (:func:`run_options`). The plant is perturbed through
:class:`~omnirotor.experiments.faults.PlantPerturbation`: the controller and the reference keep the
believed model, the simulator flies the drawn one.

Campaign file (TOML)::

    task = "sliding"            # optional when the command names the task (must agree if both do)
    runs = 24                   # default of --runs
    seed = 0                    # campaign seed
    maps = "identify-truth"     # "none" (default), "identify-truth", or a wrench-map JSON (relative to the file)
    metric = "contact.fraction" # metric of the scatter plots (default: per task, see KEY_METRICS)
    bins = 6                    # bins of the success-rate plots

    [options]                   # base options of every run (see CampaignOptions)
    quick = true
    estimator = "bypass"
    map = "nominal"             # nominal | global | piecewise (global/piecewise need maps)

    [scenario]                  # base values of ScenarioParams fields (e.g. settle_s = 1.0)

    [vary.gamma]                # one table per varied parameter (see PARAMETERS)
    dist = "uniform"
    low = 2.0
    high = 14.0

    [vary.mass_error]
    dist = "normal"             # clipped to [low, high] when given, else to the parameter's bounds
    std = 0.05

    [vary.failed_rotor]
    dist = "choice"
    values = [0, 1, 5]
    weights = [2, 1, 1]         # optional

Distributions: ``uniform`` (low, high), ``loguniform`` (low > 0, high), ``normal`` (mean = 0, std, optional
low/high clip), ``choice`` (values, optional weights), ``constant`` (value). Unknown keys, unknown
parameters, values outside a parameter's bounds, and parameters the task does not use are
:class:`~omnirotor.errors.InputError`.

Parameters (:data:`PARAMETERS`): ``mass_error`` and ``inertia_error`` (relative errors of the true mass and
inertia), ``gamma`` and ``kappa0`` (truth interference strength, SPEC §7), ``rotor_gain_error_std`` and
``rotor_tilt_error_std_deg`` (per-rotor manufacturing errors, a new airframe each run),
``scene_offset_x|y|z`` (true scene displaced from the planned one [m]), ``friction``,
``sensor_noise_scale`` (every sensor noise level scaled), ``mocap_latency_s``, ``mocap_dropout_s`` (one
dropout of that length, UKF only), ``gust_force_N`` and ``gust_duration_s`` (one horizontal 1-cos gust at the
CoM), ``failed_rotor`` (0 = none; else that rotor stops, the controller is told after 20 ms unless
``rotor_failure_told`` is false), ``peg_misalignment_deg``, ``slide_roll_deg``, and generic
``"sim.<key>"`` (plant-only simulator override), ``"controller.<key>"`` (controller override),
``"scenario.<field>"`` (protocol knob). Timed events (dropout, gust, rotor failure) start at a uniform time
in the task's contact phase (hover tasks: 2-8 s), within the run when ``duration_s`` shortens it.

``maps = "identify-truth"``: each run identifies its maps the way a user would on their robot, from hover
equilibria of that run's true plant (:func:`identify_truth_maps`), so a piecewise map matches the run's γ.

Output folder: ``campaign.json`` (the definition and its hash; a different definition in the same folder is
refused unless restarted), ``results.jsonl`` (one JSON line per finished run, appended and flushed as it
arrives, a worker's chunk of runs at a time (:func:`chunk_sizes`, at most :data:`CHUNK_MAX`): a killed campaign
resumes where it stopped, flying again the runs of the chunks under way), ``summary.json`` (success rate with
its 95 % Wilson interval, the distribution of every metric, binned success per parameter; written before the
plots, so a plotting failure never loses it) and ``plots/success-vs-<param>.png``.

Reliability (issue 14): ``.lock`` in the folder is held (``flock``) while a campaign runs, so a second
campaign into the same folder is refused; the kernel releases it when the process dies, even by SIGKILL.
Ctrl-C stops the runs under way (the results already appended are kept; run the command again to resume).
The pool's workers ignore Ctrl-C (the main process stops them) and die with the main process
(``PR_SET_PDEATHSIG``, and a watchdog thread polling the parent's pid). A run whose summary holds
non-finite values (its state blew up) is a failure, with the non-finite metrics named in ``failure``.
Backends: ``local`` (a :class:`concurrent.futures.ProcessPoolExecutor` whose workers are forked from this process,
so they share its imports, and pay their start-up once, in the pool's initializer: they load the compiled kernels
on a 10 ms run before their first job (:func:`warm_up`), then draw the plots in parallel; a run's results never
depend on which worker flew it, tested against the one-run path) or ``ray`` (the optional ``ray`` extra; a local
Ray the campaign starts, or a running cluster given by address, whose nodes need omnirotor installed).

This module runs campaigns; :mod:`omnirotor.experiments.campaigns.spec` reads their files and draws each
run's options, :mod:`omnirotor.experiments.campaigns.report` summarises and plots a campaign folder (their
public names are re-exported here). The tasks are those of SPEC §5.2; the truth model varied is SPEC §7.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import json
import math
import os
import signal
import sys
import tempfile
import threading
import time
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from omnirotor.errors import InputError
from omnirotor.experiments.campaigns.report import (
    DEFINITION_FILE,
    PLOTS_DIR,
    RESULTS_FILE,
    SUMMARY_FILE,
    binned_success,
    jsonable,
    load_results,
    metric_value,
    plot_campaign,
    plot_comparison,
    summarize,
    wilson_interval,
)
from omnirotor.experiments.campaigns.spec import (
    CAMPAIGN_TASKS,
    KEY_METRICS,
    PARAMETERS,
    CampaignOptions,
    CampaignSpec,
    Distribution,
    Parameter,
    RunJob,
    campaign_from_mapping,
    campaign_preset_names,
    expected_duration_s,
    load_campaign,
    run_options,
)
from omnirotor.experiments.tasks.common import ExperimentOptions
from omnirotor.limits import MIN_DURATION_S
from omnirotor.safe_io import append_bytes, load_json, make_dir, note, route_mujoco_log, write_json_atomic

__all__ = [
    "CampaignOptions",
    "CampaignSpec",
    "Distribution",
    "Parameter",
    "RunJob",
    "PARAMETERS",
    "CAMPAIGN_TASKS",
    "KEY_METRICS",
    "BACKENDS",
    "load_campaign",
    "campaign_from_mapping",
    "campaign_preset_names",
    "run_options",
    "identify_truth_maps",
    "execute_run",
    "warm_up",
    "run_campaign",
    "load_results",
    "summarize",
    "binned_success",
    "metric_value",
    "wilson_interval",
    "plot_campaign",
    "plot_comparison",
]

IDENTIFY_REGIONS = ("R1", "R3", "R4")
IDENTIFY_POINTS_PER_REGION = 8
"""Hover attitudes per region of :func:`identify_truth_maps` (the regions the paper flew)."""


def identify_truth_maps(options: ExperimentOptions, seed: int = 0):
    """Maps identified the way a user would on the run's robot: from hover equilibria of its true plant.

    The hover inputs balance the *true* weight under the run's truth aerodynamics (γ, κ0, rotor errors); the
    identification, like the user's, assumes the believed mass. So the maps absorb what a real
    identification would.

    Args:
        options: the run's options (its ``plant`` and simulator overrides define the truth).
        seed: seed of the hover attitudes.

    Returns:
        The :class:`~omnirotor.wrench_maps.WrenchMapSet`.
    """
    from omnirotor.experiments.tasks.scenarios import hover_attitudes
    from omnirotor.identification import HoverData, identify
    from omnirotor.regions import load_partition
    from omnirotor.sim.aero import hover_equilibrium, make_aero
    from omnirotor.vehicle import load_vehicle

    believed = load_vehicle(options.vehicle)
    plant_vehicle = options.plant.vehicle(believed) if options.plant is not None else believed
    aero = make_aero(plant_vehicle, options.plant_sim_params().aero)
    rng = np.random.default_rng([seed, 1])
    att = hover_attitudes(load_partition(), list(IDENTIFY_REGIONS), IDENTIFY_POINTS_PER_REGION, rng, believed)
    u, w = [], []
    up = np.array([0.0, 0.0, believed.weight])
    for _, R in att:
        try:
            u.append(hover_equilibrium(aero, plant_vehicle, R))
        except InputError:  # an attitude this plant cannot hold: the user would skip it too
            continue
        w.append(np.concatenate([R.T @ up, np.zeros(3)]))
    if len(u) < 6:
        raise InputError("identify-truth: the true plant holds too few hover attitudes to identify maps")
    data = HoverData(np.array(u), np.array(w), ("",) * len(u), ("truth",) * len(u))
    return identify(data, believed)


def execute_run(job: RunJob) -> dict:
    """Run one job in this process and return its record (never raises for a failed run).

    The record: ``index``, ``status`` ("ok" or "error"), ``params``, ``derived``, ``success`` (the task's
    verdict, or None), ``metrics`` (the run's summary), ``error``, ``elapsed_s``, and when they apply
    ``failure`` (why a finished run failed whatever the task's verdict) and ``warnings`` (the Python warnings
    the run raised, counted here instead of printed on the terminal by a worker).
    """
    from omnirotor.experiments.tasks import run_task

    tic = time.perf_counter()
    record: dict[str, Any] = {"index": job.index, "params": job.params, "derived": job.derived}
    caught: list = []
    try:
        options = job.options
        with (
            warnings.catch_warnings(record=True) as caught,
            tempfile.TemporaryDirectory(prefix="omnirotor-campaign-")
            if job.identify_truth
            else contextlib.nullcontext() as tmp,
        ):
            warnings.simplefilter("always")
            if job.identify_truth:
                maps_path = Path(tmp) / "maps.json"
                identify_truth_maps(options, seed=job.derived["sim_seed"]).save(maps_path)
                options = dataclasses.replace(options, maps=str(maps_path))
            summary = run_task(job.task, options).summary()
        summary.pop("figure", None)
        blown = non_finite_keys(summary)
        record.update(status="ok", success=summary.get("success"), metrics=summary, error=None)
        if blown:  # the run's state went non-finite: whatever the task's verdict, it failed
            record.update(success=False, failure=f"non-finite values in {', '.join(blown[:6])}")
    except Exception as exc:  # a campaign records a failed run and goes on
        kind = "input" if isinstance(exc, InputError) else type(exc).__name__
        where = "" if isinstance(exc, InputError) else " at " + traceback.extract_tb(exc.__traceback__)[-1].name
        record.update(status="error", success=None, metrics=None, error=f"{kind}: {exc}{where}")
    if caught:
        record["warnings"] = {"count": len(caught), "first": f"{caught[0].category.__name__}: {caught[0].message}"}
    record["elapsed_s"] = time.perf_counter() - tic
    return jsonable(record)


def non_finite_keys(obj: Any, prefix: str = "") -> list[str]:
    """Dotted names of the NaN or infinite numbers in a (nested) run summary."""
    if isinstance(obj, dict):
        return [k for key, v in obj.items() for k in non_finite_keys(v, f"{prefix}{key}.")]
    if isinstance(obj, (list, tuple)):
        return [k for i, v in enumerate(obj) for k in non_finite_keys(v, f"{prefix}{i}.")]
    if isinstance(obj, (float, np.floating)) and not math.isfinite(float(obj)):
        return [prefix[:-1]]
    return []


# -- the results file ---------------------------------------------------------------------------------------------

LOCK_FILE = ".lock"


def _append_record(path: Path, record: dict) -> None:
    """Append one JSON line with a single write, flushed to disk (never through a symbolic link)."""
    _append_records(path, [record])


def _append_records(path: Path, records: list[dict]) -> None:
    """Append one JSON line per record with a single write, flushed to disk (never through a symbolic link)."""
    lines = "".join(json.dumps(r, separators=(",", ":"), allow_nan=False) + "\n" for r in records)
    append_bytes(path, lines.encode())


@contextlib.contextmanager
def _folder_lock(out: Path):
    """Hold ``out/.lock`` (flock) for the campaign; yields its file descriptor. A second holder is refused."""
    import fcntl

    path = out / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
    except OSError as exc:
        raise InputError(f"{path}: cannot create the campaign lock ({exc.strerror})") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise InputError(f"{out}: another campaign is running into this folder (it holds {LOCK_FILE})") from None
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield fd
    finally:
        os.close(fd)  # releases the lock


def _prepare_folder(spec: CampaignSpec, out: Path, restart: bool, check_only: bool = False) -> None:
    """Create or check the campaign folder (refuses another campaign's folder unless restarting).

    With ``check_only`` nothing is written: the refusals happen before the folder or its lock exist.
    """
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    definition_path = out / DEFINITION_FILE
    digest = spec.digest()
    if definition_path.exists() and not restart:
        try:
            stored = load_json(definition_path)
            old_digest, old_def = stored["hash"], stored["definition"]
            old_digest[:12], set(old_def)  # noqa: B018  (a str and a dict, else the file is unreadable)
        except (InputError, KeyError, TypeError):
            raise InputError(f"{definition_path}: unreadable campaign definition (use --restart)") from None
        if old_digest != digest:
            new_def = spec.definition()
            changed = sorted(k for k in set(old_def) | set(new_def) if old_def.get(k) != new_def.get(k))
            raise InputError(
                f"{out} holds another campaign (hash {old_digest[:12]}, this one {digest[:12]}; changed: "
                f"{', '.join(changed) or 'definition'}); use --restart to discard its results, or another --out"
            )
        return
    if not definition_path.exists() and (out / RESULTS_FILE).exists() and not restart:
        raise InputError(f"{out} has results but no {DEFINITION_FILE}; use --restart to discard them")
    if check_only:
        return
    make_dir(out, "--out")
    if restart:
        for name in (RESULTS_FILE, SUMMARY_FILE):
            (out / name).unlink(missing_ok=True)
        plots = out / PLOTS_DIR
        if plots.is_dir():
            for p in plots.glob("success-vs-*.png"):
                p.unlink()
    write_json_atomic(definition_path, {"hash": digest, "source": spec.source, "definition": spec.definition()})


# -- running -----------------------------------------------------------------------------------------------------


BACKENDS = ("local", "ray")
"""Where a campaign's runs fly: ``local`` (a process pool on this machine) or ``ray``."""

EXECUTOR_STOP_TIMEOUT_S = 5.0
"""How long a stopped pool's manager thread gets to end [s] (:func:`stop_executor`)."""


def stop_executor(executor: cf.ProcessPoolExecutor) -> None:
    """Stop a process pool at once: kill its workers (processes it started), cancel what waits, let it wind down.

    The wait for the pool's manager thread matters at exit. Python 3.11's exit hook wakes each live manager thread
    through a pipe that the thread closes itself as it winds down; a Ctrl-C landing between the two printed
    ``OSError: Bad file descriptor`` under the one-line message. Once the thread has ended the hook has nothing
    to wake.
    """
    for proc in list((getattr(executor, "_processes", None) or {}).values()):
        with contextlib.suppress(Exception):
            proc.kill()
    manager = getattr(executor, "_executor_manager_thread", None)  # shutdown() forgets it
    executor.shutdown(wait=False, cancel_futures=True)
    if manager is not None and manager is not threading.current_thread():
        manager.join(EXECUTOR_STOP_TIMEOUT_S)


PARENT_POLL_S = 0.5
"""How often a pool worker checks that the campaign's main process is alive [s]."""


def _die_with_parent(parent_pid: int, close_fds: tuple[int, ...] = ()) -> None:
    """Pool-worker initializer: ignore Ctrl-C and exit when the main process dies.

    The main process stops the pool on Ctrl-C. Death of the main process is caught by the kernel's
    parent-death signal (Linux), and by a thread polling the parent's pid elsewhere.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for fd in close_fds:  # the folder lock stays the main process's alone
        with contextlib.suppress(OSError):
            os.close(fd)
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="omnirotor-parent-watch", daemon=True).start()


def warm_up(job: RunJob) -> None:
    """Load what runs like ``job`` use (the compiled kernels from numba's cache, lazily imported modules).

    Flies ``job`` for the shortest duration allowed, without identification or maps (their kernels are the
    same) and discards the record. A run's results never depend on this: every run builds its plant and
    controller afresh from its own seed. A failure here is left for the real run to report.
    """
    options = dataclasses.replace(job.options, duration_s=MIN_DURATION_S)
    if job.identify_truth:
        options = dataclasses.replace(options, map_mode="nominal", maps=None)
    with contextlib.suppress(Exception):
        execute_run(dataclasses.replace(job, options=options, identify_truth=False))


def _start_worker(parent_pid: int, close_fds: tuple[int, ...], warm: RunJob | None) -> None:
    """Pool-worker initializer: :func:`_die_with_parent`, then :func:`warm_up` while the pool is being filled."""
    _die_with_parent(parent_pid, close_fds)
    if warm is not None:
        warm_up(warm)


@contextlib.contextmanager
def _local_pool(jobs: list[RunJob], workers: int, lock_fd: int | None = None):
    """A process pool of ``workers`` for ``jobs`` (None for one worker: the runs then fly in this process).

    The workers are forked from this process (its imports are theirs) and warm up (:func:`warm_up`) in parallel
    before their first run; after the runs they draw the plots (each imports matplotlib then). Leaving the block
    early (Ctrl-C, an error) kills the runs under way at once.
    """
    if workers == 1:
        yield None
        return
    pool = cf.ProcessPoolExecutor(
        max_workers=workers,
        initializer=_start_worker,
        initargs=(os.getpid(), (lock_fd,) if lock_fd is not None else (), jobs[0]),
    )
    finished = False
    try:
        yield pool
        finished = True
    finally:
        if finished:
            pool.shutdown(wait=True)
        else:  # interrupted or failed: stop the runs under way now, not when they end
            stop_executor(pool)


RAY_CONNECT_TIMEOUT_S = 5.0
"""A cluster address must accept a TCP connection within this time [s] (Ray itself retries for minutes)."""


def _check_reachable(address: str) -> None:
    """Refuse a ``host:port`` (or ``ray://host:port``) nobody listens on, before Ray retries it at length."""
    import socket

    if address in ("auto", "local"):
        return
    target = address.removeprefix("ray://")
    host, _, port = target.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InputError(f"--address {address!r}: expected host:port, ray://host:port or auto")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=RAY_CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise InputError(f"--address {address}: cannot reach the Ray cluster ({exc.strerror or exc})") from None


def _ray_connect(workers: int | None, address: str | None):
    """Start a local Ray, or connect to the cluster at ``address``; returns (the ray module, started here)."""
    try:
        import ray
    except ImportError:
        raise InputError("--backend ray needs the optional dependency ray: pip install 'omnirotor[ray]'") from None
    started = not ray.is_initialized()
    if started:
        # PYTHONSAFEPATH: a worker puts no working folder first on its sys.path (no code from where Ray runs it)
        safe = {"env_vars": {"PYTHONSAFEPATH": "1"}}
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "runtime_env": safe}
        if address is not None:
            _check_reachable(address)
            kwargs["address"] = address
        elif workers is not None:
            kwargs["num_cpus"] = workers
        try:
            ray.init(**kwargs)
        except (ConnectionError, ValueError, RuntimeError) as exc:
            raise InputError(f"ray: cannot connect to {address or 'a local Ray'} ({exc})") from None
    return ray, started


def _ray_backend(ray, jobs: list[RunJob], workers: int | None):
    """Yield records as the runs finish, on Ray (connected by :func:`_ray_connect`)."""
    remote = ray.remote(num_cpus=1, max_retries=0)(execute_run)
    limit = workers if workers is not None else len(jobs)
    pending: list = []
    queue = list(jobs)
    try:
        while queue or pending:
            while queue and len(pending) < limit:
                pending.append(remote.remote(queue.pop(0)))
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                yield ray.get(ref)
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)


def run_campaign(
    spec: CampaignSpec,
    out_dir: str | Path,
    runs: int | None = None,
    backend: str = "local",
    workers: int | None = None,
    address: str | None = None,
    restart: bool = False,
    progress: Callable[[int, int, dict | None], None] | None = None,
    plots: bool = True,
) -> dict:
    """Run the runs of a campaign not yet in ``out_dir``, then summarise and plot.

    Args:
        spec: the campaign.
        out_dir: the campaign folder (module docstring).
        runs: number of runs (None: ``spec.runs``); indices ``0 .. runs-1``, those done are skipped.
        backend: "local" or "ray".
        workers: parallel runs (local default: the CPU count, 1 runs them in this process; ray default: as the
            cluster allows).
        address: Ray cluster address (ray backend only; None starts a local Ray).
        restart: discard the folder's results first (also when its definition differs).
        progress: called with (runs done, runs requested, the record just finished or None).
        plots: write the PNG plots.

    Returns:
        The summary (also in ``DIR/summary.json``), with ``executed``: the runs this call ran.

    Raises:
        InputError: bad arguments, or a folder holding another campaign without ``restart``.
    """
    n = spec.runs if runs is None else runs
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise InputError(f"--runs must be an integer >= 1, got {n!r}")
    if backend not in BACKENDS:
        raise InputError(f"--backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InputError(f"--workers must be an integer >= 1, got {workers!r}")
    if address is not None and backend != "ray":
        raise InputError("--address needs --backend ray")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    ray, started = _ray_connect(workers, address) if backend == "ray" else (None, False)
    try:
        return _run(spec, out, n, backend, workers, ray, restart, progress, plots)
    finally:
        if started:
            ray.shutdown()


def _run(spec, out: Path, n: int, backend: str, workers, ray, restart: bool, progress, plots: bool) -> dict:
    """:func:`run_campaign` once the backend is up."""
    _prepare_folder(spec, out, restart, check_only=True)  # refuse before writing anything
    make_dir(out, "--out")
    with _folder_lock(out) as lock_fd:
        return _run_locked(spec, out, n, backend, workers, ray, restart, progress, plots, lock_fd)


CHUNK_MAX = 8
"""Most runs sent to a worker in one request (:func:`chunk_sizes`)."""
CHUNKS_PER_WORKER = 4
"""A chunk is at most the runs left over this many times the workers (:func:`chunk_sizes`)."""


def chunk_sizes(n: int, workers: int) -> list[int]:
    """Runs per request for ``n`` runs on ``workers`` (guided self-scheduling): fewer round trips, a short tail.

    Each request takes the runs left over :data:`CHUNKS_PER_WORKER` times the workers, at most :data:`CHUNK_MAX`
    and at least one, so the requests shrink to single runs at the end and the workers finish together.
    """
    sizes = []
    left = n
    while left > 0:
        k = max(1, min(CHUNK_MAX, -(-left // (CHUNKS_PER_WORKER * max(1, workers)))))
        sizes.append(k)
        left -= k
    return sizes


def longest_first(jobs: list[RunJob]) -> list[RunJob]:
    """``jobs`` in the order they are sent: the longest runs first (:func:`expected_duration_s`), else as given.

    Runs of unequal length sent in index order can leave one worker stepping a long run alone at the end while
    the others wait; sent longest first, the short ones fill the gaps (the longest-processing-time rule). Runs of
    equal length (most campaigns) keep their index order. A run's record never depends on its place.
    """
    lengths = [expected_duration_s(job) for job in jobs]
    if None in lengths or len(set(lengths)) <= 1:
        return list(jobs)
    order = sorted(range(len(jobs)), key=lambda i: -lengths[i])  # stable: index order among equals
    return [jobs[i] for i in order]


def run_chunk(run_fn: Callable[[RunJob], dict], jobs: list[RunJob]) -> list[dict]:
    """The records of ``jobs`` run one after the other by ``run_fn`` (one request to a worker)."""
    return [run_fn(job) for job in jobs]


def _executor_backend(executor: cf.Executor, jobs: list[RunJob], limit: int):
    """Yield lists of records as chunks of runs finish on the pool's workers, at most ``limit`` at a time.

    The jobs go in order, in chunks of :func:`chunk_sizes` (one request and one answer per chunk). A ``limit`` of
    all the executor's workers queues every chunk at once, so that no worker waits for this process (writing a
    result, say) between runs. When the consumer stops early, the pool's owner kills the pool.
    """
    workers = getattr(executor, "_max_workers", limit)
    if limit >= workers:
        limit = len(jobs)
    queue, i = [], 0
    for k in chunk_sizes(len(jobs), min(workers, limit)):
        queue.append(jobs[i : i + k])
        i += k
    queue.reverse()
    pending: set[cf.Future] = set()
    while queue or pending:
        while queue and len(pending) < limit:
            pending.add(executor.submit(run_chunk, execute_run, queue.pop()))
        done, pending = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
        for fut in done:
            yield fut.result()


def _run_locked(spec, out: Path, n: int, backend: str, workers, ray, restart: bool, progress, plots, lock_fd) -> dict:
    """:func:`_run` holding the folder's lock."""
    _prepare_folder(spec, out, restart)
    route_mujoco_log(out)  # the workers inherit it
    done = {i: r for i, r in load_results(out, repair=True).items() if i < n}
    todo = [i for i in range(n) if i not in done]
    report = progress or (lambda k, total, rec: None)
    report(len(done), n, None)
    jobs = []
    for i in todo:
        try:
            jobs.append(run_options(spec, i))
        except InputError as exc:  # this draw is invalid: record it as a failed run
            rec = jsonable({"index": i, "status": "error", "params": {}, "derived": {}, "success": None,
                             "metrics": None, "error": f"input: {exc}", "elapsed_s": 0.0})  # fmt: skip
            _append_record(out / RESULTS_FILE, rec)
            done[i] = rec
    count = len(done)
    report(count, n, None)
    jobs = longest_first(jobs)
    if backend == "local" and jobs:  # the command's own pool: runs, then plots
        pool_cm = _local_pool(jobs, workers or min(len(jobs), os.cpu_count() or 1), lock_fd)
    else:
        pool_cm = contextlib.nullcontext(None)
    with pool_cm as executor:
        if jobs:
            if backend == "local" and executor is not None:
                batches = _executor_backend(executor, jobs, workers or executor._max_workers)
            elif backend == "local":
                batches = ([execute_run(job)] for job in jobs)
            else:
                batches = ([rec] for rec in _ray_backend(ray, jobs, workers))
            for batch in batches:
                _append_records(out / RESULTS_FILE, batch)  # one write and sync per chunk
                for rec in batch:
                    done[rec["index"]] = rec
                    count += 1
                    report(count, n, rec)
        return _finish(spec, out, n, done, len(jobs), plots, executor, workers)


def _finish(spec, out: Path, n: int, done: dict, executed: int, plots: bool, executor, workers) -> dict:
    """Summarise the campaign folder's records, then plot (on ``workers`` of ``executor``'s when given)."""
    records = [done[i] for i in sorted(done)]
    summary = summarize(spec, records, n)
    summary["executed"] = executed
    write_json_atomic(out / SUMMARY_FILE, summary)  # before the plots: a plotting failure never loses it
    if plots:
        try:
            summary["plots"] = [str(p) for p in plot_campaign(spec, records, out / PLOTS_DIR, executor, workers)]
        except Exception as exc:  # the summary stands; say what went wrong with the plots
            summary["plots_error"] = f"{type(exc).__name__}: {exc}"
            note(f"campaign plots failed ({summary['plots_error'][:200]}); {out / SUMMARY_FILE} is written")
        write_json_atomic(out / SUMMARY_FILE, summary)
    return summary
