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
arrives: a killed campaign resumes where it stopped), ``summary.json`` (success rate with its 95 % Wilson
interval, the distribution of every metric, binned success per parameter) and ``plots/success-vs-<param>.png``.
Backends: ``local`` (a :class:`concurrent.futures.ProcessPoolExecutor`) or ``ray`` (the optional ``ray``
extra; a local Ray the campaign starts, or a running cluster given by address, whose nodes need omnirotor
installed).
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import hashlib
import json
import math
import os
import tempfile
import time
import traceback
from collections.abc import Callable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from omnirotor.config import apply_overrides, from_mapping, load_toml
from omnirotor.errors import InputError
from omnirotor.experiments.faults import MocapDropout, PlantPerturbation, RotorFailure, WindGust
from omnirotor.experiments.scenarios import ScenarioParams
from omnirotor.experiments.tasks import CONTACT_TASKS, HOVER_TASKS, MAP_MODES, ExperimentOptions
from omnirotor.sim.params import SensorParams, SimParams
from omnirotor.wrench_maps import write_json_atomic

__all__ = [
    "CampaignOptions",
    "CampaignSpec",
    "Distribution",
    "Parameter",
    "PARAMETERS",
    "CAMPAIGN_TASKS",
    "KEY_METRICS",
    "BACKENDS",
    "load_campaign",
    "campaign_preset_names",
    "run_options",
    "identify_truth_maps",
    "execute_run",
    "run_campaign",
    "load_results",
    "summarize",
    "plot_campaign",
    "plot_comparison",
]

CAMPAIGN_TASKS = CONTACT_TASKS + HOVER_TASKS
"""Tasks a campaign can run: the experiment tasks, which fly the perturbed plant."""
KEY_METRICS = {
    "sliding": "contact.fraction",
    "peg-in-hole": "insertion.max_depth_m",
    "point-contact": "normal_force.true_mean_N",
    "point-contact-tilted": "normal_force.true_mean_N",
    "identify-flights": "ee_rms_error.z_cm",
    "hover-validation": "ee_rms_error.z_cm",
}
"""Default metric of the scatter plots, per task (dotted path into the run's summary)."""
BACKENDS = ("local", "ray")
DISTRIBUTIONS = {
    "uniform": ({"low", "high"}, set()),
    "loguniform": ({"low", "high"}, set()),
    "normal": ({"std"}, {"mean", "low", "high"}),
    "choice": ({"values"}, {"weights"}),
    "constant": ({"value"}, set()),
}
"""Required and optional keys of each distribution."""
HOVER_EVENT_WINDOW_S = (2.0, 8.0)
"""Timed events of the hover tasks start in this window [s]."""
ROTOR_DETECT_DELAY_S = 0.02
"""Time from a rotor failure to the controller being told in campaigns [s] (ESC telemetry, [A])."""
IDENTIFY_REGIONS = ("R1", "R3", "R4")
IDENTIFY_POINTS_PER_REGION = 8
"""Hover attitudes per region of :func:`identify_truth_maps` (the regions the paper flew)."""
_SEED_MAX = 2**31 - 1
_RESULTS = "results.jsonl"
_DEFINITION = "campaign.json"
_SUMMARY = "summary.json"
_PLOTS = "plots"


# -- parameters --------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Parameter:
    """A parameter a campaign can vary.

    Attributes:
        name: its name in ``[vary.NAME]``.
        help: what it changes.
        unit: unit of its values ("" when relative or a count).
        low: smallest allowed value (None: unbounded).
        high: largest allowed value (None: unbounded).
        tasks: the tasks it applies to (None: every campaign task).
        kind: "float", "int" or "bool".
        needs_ukf: only meaningful with the UKF estimator (it acts on motion capture).
    """

    name: str
    help: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    tasks: tuple[str, ...] | None = None
    kind: str = "float"
    needs_ukf: bool = False


_P = Parameter
PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        _P("mass_error", "relative error of the true mass: m_true = m (1 + e)", "", -0.9, 10.0),
        _P("inertia_error", "relative error of the true inertia (every axis): J_true = J (1 + e)", "", -0.9, 10.0),
        _P("gamma", "inflow sensitivity of the truth interference model (SPEC §7; 4 = calibrated)", "", 0.0),
        _P("kappa0", "isolated-rotor thrust gain of the truth model (SPEC §7; 1.18 = calibrated)", "", 1e-3),
        _P("rotor_gain_error_std", "per-rotor relative thrust-gain error, standard deviation", "", 0.0, 0.5),
        _P("rotor_tilt_error_std_deg", "per-rotor axis tilt error, standard deviation", "deg", 0.0, 30.0),
        _P("scene_offset_x", "true scene displaced along world x from the planned one", "m", tasks=CONTACT_TASKS),
        _P("scene_offset_y", "true scene displaced along world y from the planned one", "m", tasks=CONTACT_TASKS),
        _P("scene_offset_z", "true scene displaced along world z from the planned one", "m", tasks=CONTACT_TASKS),
        _P("friction", "sliding friction coefficient of every contact", "", 0.0, tasks=CONTACT_TASKS),
        _P("sensor_noise_scale", "every sensor noise level multiplied by this", "", 0.0),
        _P("mocap_latency_s", "motion-capture latency", "s", 0.0, 0.2, needs_ukf=True),
        _P("mocap_dropout_s", "length of one motion-capture dropout (0 = none)", "s", 0.0, needs_ukf=True),
        _P("gust_force_N", "peak force of one horizontal 1-cos gust at the CoM (0 = none)", "N", 0.0),
        _P("gust_duration_s", "length of the gust", "s", 1e-3),
        _P("failed_rotor", "rotor that stops (numbered from 1; 0 = none)", "", 0, kind="int"),
        _P("rotor_failure_told", "whether the controller is told of the failed rotor", "", kind="bool"),
        _P("peg_misalignment_deg", "approach roll misalignment of the peg", "deg", -60.0, 60.0, ("peg-in-hole",)),
        _P("slide_roll_deg", "roll at the apex of the pipe", "deg", 0.0, 80.0, ("sliding",)),
    )
}
"""The named parameters; ``sim.<key>``, ``controller.<key>`` and ``scenario.<field>`` are accepted too."""
_GENERIC_PREFIXES = ("sim.", "controller.", "scenario.")
_NOISE_FIELDS = tuple(
    f.name for f in dataclasses.fields(SensorParams) if f.name.endswith("_std") or f.name.endswith("_std_hz")
)


def _parameter(name: str) -> Parameter:
    if name in PARAMETERS:
        return PARAMETERS[name]
    if name.startswith(_GENERIC_PREFIXES) and len(name.split(".", 1)[1]) > 0:
        return Parameter(name, "generic override", kind="any")
    raise InputError(
        f"unknown parameter {name!r}; parameters: {', '.join(PARAMETERS)}, or sim.<key>, controller.<key>, "
        "scenario.<field>"
    )


# -- distributions -----------------------------------------------------------------------------------------------


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


@dataclasses.dataclass(frozen=True)
class Distribution:
    """How one parameter is drawn (module docstring).

    Attributes:
        dist: "uniform", "loguniform", "normal", "choice" or "constant".
        low: lower end (uniform, loguniform) or clip (normal).
        high: upper end (uniform, loguniform) or clip (normal).
        mean: mean of a normal (default 0).
        std: standard deviation of a normal.
        values: the choices.
        weights: relative weights of the choices (default equal).
        value: the constant.
    """

    dist: str
    low: float | None = None
    high: float | None = None
    mean: float | None = None
    std: float | None = None
    values: tuple[object, ...] | None = None
    weights: tuple[float, ...] | None = None
    value: object = None

    def __post_init__(self) -> None:
        if self.dist not in DISTRIBUTIONS:
            raise InputError(f"dist must be one of {', '.join(DISTRIBUTIONS)}, got {self.dist!r}")
        required, optional = DISTRIBUTIONS[self.dist]
        given = {f.name for f in dataclasses.fields(self) if f.name != "dist" and getattr(self, f.name) is not None}
        if required - given:
            raise InputError(f'dist = "{self.dist}" needs {", ".join(sorted(required - given))}')
        if given - required - optional:
            raise InputError(f'dist = "{self.dist}" takes no {", ".join(sorted(given - required - optional))}')
        for name in ("low", "high", "mean", "std"):
            v = getattr(self, name)
            if v is not None and not math.isfinite(v):
                raise InputError(f"{name} must be finite, got {v}")
        if self.dist in ("uniform", "loguniform") and not self.low < self.high:
            raise InputError(f"low must be < high, got {self.low} and {self.high}")
        if self.dist == "loguniform" and self.low <= 0:
            raise InputError(f"loguniform needs low > 0, got {self.low}")
        if self.dist == "normal":
            if self.std <= 0:
                raise InputError(f"std must be > 0, got {self.std}")
            if self.low is not None and self.high is not None and not self.low < self.high:
                raise InputError(f"low must be < high, got {self.low} and {self.high}")
        if self.dist == "choice":
            vals = self.values
            if not vals:
                raise InputError("values must be a non-empty array")
            if all(_is_number(v) for v in vals):
                if not all(math.isfinite(v) for v in vals):
                    raise InputError("values must be finite")
            elif not (all(isinstance(v, bool) for v in vals) or all(isinstance(v, str) for v in vals)):
                raise InputError("values must be all numbers, all booleans or all strings")
            if self.weights is not None:
                w = self.weights
                if len(w) != len(vals) or not all(math.isfinite(x) and x >= 0 for x in w) or sum(w) <= 0:
                    raise InputError("weights must be one finite number >= 0 per value, not all 0")
        if self.dist == "constant":
            v = self.value
            if not (isinstance(v, (bool, str)) or (_is_number(v) and math.isfinite(v))):
                raise InputError(f"value must be a finite number, a boolean or a string, got {v!r}")

    def support(self) -> tuple[Any, ...]:
        """Values that bound what can be drawn (the ends, or every choice)."""
        if self.dist in ("uniform", "loguniform"):
            return (self.low, self.high)
        if self.dist == "normal":
            return tuple(v for v in (self.low, self.high) if v is not None)
        if self.dist == "choice":
            return tuple(self.values)
        return (self.value,)

    def typical(self) -> Any:
        """One value of the distribution (to check a generic override's key before any run)."""
        if self.dist == "normal":
            return self.mean or 0.0
        return self.support()[0]

    def draw(self, rng: np.random.Generator, low: float | None = None, high: float | None = None) -> Any:
        """One value; a normal is clipped to its ``low``/``high``, else to the given bounds."""
        if self.dist == "uniform":
            return float(rng.uniform(self.low, self.high))
        if self.dist == "loguniform":
            return float(math.exp(rng.uniform(math.log(self.low), math.log(self.high))))
        if self.dist == "normal":
            x = float(rng.normal(self.mean or 0.0, self.std))
            lo = self.low if self.low is not None else low
            hi = self.high if self.high is not None else high
            if lo is not None:
                x = max(x, lo)
            if hi is not None:
                x = min(x, hi)
            return x
        if self.dist == "choice":
            p = None
            if self.weights is not None:
                w = np.asarray(self.weights, dtype=float)
                p = w / w.sum()
            return self.values[int(rng.choice(len(self.values), p=p))]
        return self.value

    def to_dict(self) -> dict:
        """The table as in the file (only the keys given)."""
        out: dict[str, Any] = {"dist": self.dist}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name != "dist" and v is not None:
                out[f.name] = list(v) if isinstance(v, tuple) else v
        return out


# -- campaign definition -----------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class CampaignOptions:
    """Base options of every run of a campaign (the ``[options]`` table).

    Attributes:
        map: wrench map in the loop: "nominal", "global" or "piecewise".
        blend: piecewise region switching, "hard" or "smooth".
        quick: shortened protocols.
        estimator: "ukf" or "bypass".
        solver: allocation QP backend, "daqp" or "proxsuite".
        truth: truth aerodynamics, "interference" or "nominal".
        vehicle: vehicle preset or TOML file.
        duration_s: simulated time of each run [s] (None: the task's).
        zero_observer: zero the observer at the start (None: the task's default).
        controller_config: controller TOML file, or None.
        controller_overrides: controller ``key=value`` overrides.
        sim_overrides: simulator ``key=value`` overrides (plant and plan alike).
    """

    map: str = "nominal"
    blend: str = "hard"
    quick: bool = False
    estimator: str = "ukf"
    solver: str = "daqp"
    truth: str = "interference"
    vehicle: str = "omnirotor"
    duration_s: float | None = None
    zero_observer: bool | None = None
    controller_config: str | None = None
    controller_overrides: tuple[str, ...] = ()
    sim_overrides: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.map not in MAP_MODES:
            raise InputError(f"options.map must be one of {', '.join(MAP_MODES)}, got {self.map!r}")
        if self.blend not in ("hard", "smooth"):
            raise InputError(f"options.blend must be hard or smooth, got {self.blend!r}")


@dataclasses.dataclass(frozen=True)
class CampaignSpec:
    """A campaign definition (module docstring); :meth:`definition` is what its hash covers.

    Attributes:
        task: the task.
        seed: campaign seed.
        maps: "none", "identify-truth" or a wrench-map JSON path.
        options: base options.
        scenario: base ScenarioParams values, as (field, value) pairs.
        vary: (parameter name, distribution) pairs, sorted by name.
        runs: default number of runs.
        metric: metric of the scatter plots (None: the task's :data:`KEY_METRICS`).
        bins: bins of the success-rate plots.
        source: the file it was read from (not part of the definition).
    """

    task: str
    seed: int = 0
    maps: str = "none"
    options: CampaignOptions = dataclasses.field(default_factory=CampaignOptions)
    scenario: tuple[tuple[str, Any], ...] = ()
    vary: tuple[tuple[str, Distribution], ...] = ()
    runs: int = 20
    metric: str | None = None
    bins: int = 6
    source: str | None = None

    @property
    def key_metric(self) -> str:
        """The metric of the scatter plots."""
        return self.metric or KEY_METRICS.get(self.task, "ee_rms_error.x_cm")

    def definition(self) -> dict:
        """Everything that determines the runs' results, as plain data (hashed by :meth:`digest`)."""
        maps: Any = self.maps
        if self.maps not in ("none", "identify-truth"):
            maps = {"file": self.maps, "sha256": _file_digest(self.maps)}
        return {
            "task": self.task,
            "seed": self.seed,
            "maps": maps,
            "options": {
                f.name: list(v) if isinstance(v := getattr(self.options, f.name), tuple) else v
                for f in dataclasses.fields(self.options)
            },
            "scenario": dict(self.scenario),
            "vary": {name: d.to_dict() for name, d in self.vary},
        }

    def digest(self) -> str:
        """SHA-256 of the canonical JSON of :meth:`definition`."""
        text = json.dumps(self.definition(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def _file_digest(path: str) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None


def campaign_preset_names() -> list[str]:
    """Names of the campaign presets shipped with the package."""
    files = resources.files("omnirotor") / "presets" / "campaigns"
    return sorted(p.name[: -len(".toml")] for p in files.iterdir() if p.name.endswith(".toml"))


_TOP_KEYS = {"task", "runs", "seed", "maps", "metric", "bins", "options", "scenario", "vary"}


def load_campaign(spec: str | Path | None = None, task: str | None = None, **overrides: Any) -> CampaignSpec:
    """Read a campaign file (or preset name) and apply command-line overrides.

    Args:
        spec: campaign TOML file or preset name (None: the ``default`` preset).
        task: the task named on the command line (None: the file's).
        **overrides: ``seed``, ``maps``, ``map`` (None values are ignored) and ``quick`` (True forces it on).

    Raises:
        InputError: unreadable file, unknown key or parameter, bad value, a task that disagrees with the
            file's, or a parameter the task does not use.
    """
    text = "default" if spec is None else str(spec)
    if text in campaign_preset_names():
        path = Path(str(resources.files("omnirotor") / "presets" / "campaigns" / f"{text}.toml"))
        where, base_dir = f"campaign preset {text}", None
    else:
        path = Path(text)
        if not path.suffix and not path.exists():
            raise InputError(f"unknown campaign {text!r}: no such file; presets: {', '.join(campaign_preset_names())}")
        where, base_dir = str(path), path.resolve().parent
    data = load_toml(path)
    return campaign_from_mapping(data, where, base_dir, task, **overrides)


def _resolve(path_text: str, base_dir: Path | None) -> str:
    p = Path(path_text)
    return str(p if p.is_absolute() or base_dir is None else base_dir / p)


def campaign_from_mapping(
    data: Mapping[str, Any], where: str = "campaign", base_dir: Path | None = None, task: str | None = None, **ov: Any
) -> CampaignSpec:
    """Build a :class:`CampaignSpec` from a parsed campaign table (see :func:`load_campaign`)."""
    if not isinstance(data, Mapping):
        raise InputError(f"{where}: expected a table")
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(_TOP_KEYS))}")
    file_task = data.get("task")
    if file_task is not None and not isinstance(file_task, str):
        raise InputError(f"{where}: task must be a string")
    if task is not None and file_task is not None and task != file_task:
        raise InputError(f"{where} is a campaign of task {file_task!r}, not {task!r}")
    name = task or file_task
    if name is None:
        raise InputError(f"{where}: no task (name one on the command line or set task = ... in the file)")
    if name not in CAMPAIGN_TASKS:
        raise InputError(f"campaigns run the tasks {', '.join(CAMPAIGN_TASKS)}; got {name!r}")
    scalars = {}
    for key, tp, default in (("runs", int, 20), ("seed", int, 0), ("bins", int, 6), ("maps", str, "none")):
        v = data.get(key, default)
        if isinstance(v, bool) or not isinstance(v, tp):
            raise InputError(f"{where}: {key} must be {'an integer' if tp is int else 'a string'}, got {v!r}")
        scalars[key] = v
    metric = data.get("metric")
    if metric is not None and (not isinstance(metric, str) or not metric):
        raise InputError(f"{where}: metric must be a dotted metric name, got {metric!r}")
    if ov.get("seed") is not None:
        scalars["seed"] = ov["seed"]
    if ov.get("maps") is not None:
        scalars["maps"] = str(ov["maps"])
    elif scalars["maps"] not in ("none", "identify-truth"):
        scalars["maps"] = _resolve(scalars["maps"], base_dir)
    if isinstance(scalars["seed"], bool) or not isinstance(scalars["seed"], int) or scalars["seed"] < 0:
        raise InputError(f"{where}: seed must be an integer >= 0, got {scalars['seed']!r}")
    if scalars["runs"] < 1:
        raise InputError(f"{where}: runs must be >= 1, got {scalars['runs']}")
    if not 1 <= scalars["bins"] <= 50:
        raise InputError(f"{where}: bins must be in 1..50, got {scalars['bins']}")
    maps = scalars["maps"]
    if maps not in ("none", "identify-truth") and not Path(maps).is_file():
        raise InputError(f"maps {maps}: no such file (or use 'identify-truth' or 'none')")
    opt_table = data.get("options", {})
    if not isinstance(opt_table, Mapping):
        raise InputError(f"{where}: [options] must be a table")
    opt_table = dict(opt_table)
    if ov.get("map") is not None:
        opt_table["map"] = ov["map"]
    if ov.get("quick"):  # --quick shortens; its absence keeps the file's choice
        opt_table["quick"] = True
    options = from_mapping(CampaignOptions, opt_table, f"{where} [options]")
    for key in ("vehicle", "controller_config"):
        v = getattr(options, key)
        if v is not None and (key == "controller_config" or Path(v).suffix):
            options = dataclasses.replace(options, **{key: _resolve(v, base_dir)})
    if options.map != "nominal" and maps == "none":
        raise InputError(
            f"map {options.map!r} needs maps: a wrench-map file, or 'identify-truth' to identify each run's own "
            "maps from its true plant"
        )
    scen = data.get("scenario", {})
    if not isinstance(scen, Mapping):
        raise InputError(f"{where}: [scenario] must be a table")
    from_mapping(ScenarioParams, scen, f"{where} [scenario]")  # check keys and types
    vary_table = data.get("vary", {})
    if not isinstance(vary_table, Mapping):
        raise InputError(f"{where}: [vary] must hold one table per parameter")
    vary = []
    for pname in sorted(vary_table):
        table = vary_table[pname]
        if not isinstance(table, Mapping):
            raise InputError(f'{where}: vary.{pname} must be a table like {{dist = "uniform", low = 0, high = 1}}')
        par = _parameter(pname)
        dist = from_mapping(Distribution, table, f"{where} vary.{pname}")
        _check_parameter(par, dist, name, options, f"{where} vary.{pname}")
        vary.append((pname, dist))
    spec = CampaignSpec(
        task=name,
        seed=scalars["seed"],
        maps=maps,
        options=options,
        scenario=tuple(sorted(scen.items())),
        vary=tuple(vary),
        runs=scalars["runs"],
        metric=metric,
        bins=scalars["bins"],
        source=where,
    )
    _dry_run(spec)
    return spec


def _check_parameter(par: Parameter, dist: Distribution, task: str, options: CampaignOptions, where: str) -> None:
    if par.tasks is not None and task not in par.tasks:
        raise InputError(f"{where}: {par.name} applies to {', '.join(par.tasks)} only, not {task}")
    if par.needs_ukf and options.estimator != "ukf":
        raise InputError(f'{where}: {par.name} acts on motion capture, which only the "ukf" estimator reads')
    support = dist.support()
    if par.kind == "bool":
        if dist.dist not in ("choice", "constant") or not all(isinstance(v, bool) for v in support):
            raise InputError(f"{where}: {par.name} takes true/false (choice or constant)")
        return
    if par.kind == "any":
        _check_generic(par.name, dist.typical(), where)
        return
    if not all(_is_number(v) for v in support):
        raise InputError(f"{where}: {par.name} takes numbers")
    if par.kind == "int" and (dist.dist not in ("choice", "constant") or not all(isinstance(v, int) for v in support)):
        raise InputError(f"{where}: {par.name} takes integers (choice or constant)")
    for v in support:
        if (par.low is not None and v < par.low) or (par.high is not None and v > par.high):
            lo = "-inf" if par.low is None else f"{par.low:g}"
            hi = "inf" if par.high is None else f"{par.high:g}"
            raise InputError(f"{where}: {par.name} = {v} is outside [{lo}, {hi}]")


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(float(v)) if isinstance(v, float) else repr(v)


def _check_generic(name: str, value: Any, where: str) -> None:
    group, key = name.split(".", 1)
    override = [f"{key}={_toml_value(value)}"]
    try:
        if group == "sim":
            apply_overrides(SimParams(), override)
        elif group == "controller":
            from omnirotor.control.controller import ControllerParams

            apply_overrides(ControllerParams(), override)
        else:
            apply_overrides(ScenarioParams(), override)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


# -- one run ----------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RunJob:
    """Everything a worker needs for run ``index`` (picklable; see :func:`execute_run`).

    Attributes:
        index: run index.
        task: task name.
        options: the run's options (``maps`` is replaced by identified maps for "identify-truth").
        params: the drawn parameter values.
        derived: the derived draws (seeds, event times).
        identify_truth: identify the run's maps from its true plant first.
    """

    index: int
    task: str
    options: ExperimentOptions
    params: dict
    derived: dict
    identify_truth: bool = False


def _event_window(spec: CampaignSpec, sp: ScenarioParams) -> tuple[float, float]:
    from omnirotor.experiments import scenarios

    if spec.task in CONTACT_TASKS:
        builder = {
            "point-contact": scenarios.point_contact,
            "point-contact-tilted": scenarios.point_contact_tilted,
            "sliding": scenarios.sliding,
            "peg-in-hole": scenarios.peg_in_hole,
        }[spec.task]
        t0, t1 = builder(SimParams().scene, sp, quick=spec.options.quick).contact_phase
    else:
        t0, t1 = HOVER_EVENT_WINDOW_S
    d = spec.options.duration_s
    if d is not None and spec.task in CONTACT_TASKS and t1 > 0.75 * d:
        t1 = 0.75 * d
        t0 = min(t0, 0.25 * d)
    return float(t0), float(t1)


def run_options(spec: CampaignSpec, index: int) -> RunJob:
    """The options of run ``index``: parameters drawn from ``default_rng([spec.seed, index])``.

    Raises:
        InputError: a drawn combination is invalid (e.g. a non-physical inertia).
    """
    rng = np.random.default_rng([spec.seed, index])
    params: dict[str, Any] = {}
    for name, dist in spec.vary:
        par = _parameter(name)
        v = dist.draw(rng, par.low, par.high)
        params[name] = int(v) if par.kind == "int" else v
    derived: dict[str, Any] = {
        "sim_seed": int(rng.integers(_SEED_MAX)),
        "rotor_error_seed": int(rng.integers(_SEED_MAX)),
    }
    o = spec.options
    base_sp = ScenarioParams(segment_s=2.0, settle_s=1.0) if o.quick else ScenarioParams()
    scen = dict(spec.scenario)
    plant_over: list[str] = []
    ctl_over = list(o.controller_overrides)
    mass, inertia = 1.0, 1.0
    offset = [0.0, 0.0, 0.0]
    noise = 1.0
    for name, v in params.items():
        if name == "mass_error":
            mass = 1.0 + v
        elif name == "inertia_error":
            inertia = 1.0 + v
        elif name in ("gamma", "kappa0"):
            plant_over.append(f"aero.{name}={_toml_value(float(v))}")
        elif name == "rotor_gain_error_std":
            plant_over += [
                f"aero.gain_error_std={_toml_value(float(v))}",
                f"aero.error_seed={derived['rotor_error_seed']}",
            ]
        elif name == "rotor_tilt_error_std_deg":
            plant_over += [
                f"aero.tilt_error_std_deg={_toml_value(float(v))}",
                f"aero.error_seed={derived['rotor_error_seed']}",
            ]
        elif name.startswith("scene_offset_"):
            offset["xyz".index(name[-1])] = float(v)
        elif name == "friction":
            plant_over.append(f"scene.friction={_toml_value(float(v))}")
        elif name == "sensor_noise_scale":
            noise = float(v)
        elif name == "mocap_latency_s":
            plant_over.append(f"sensors.mocap_latency_s={_toml_value(float(v))}")
        elif name in ("peg_misalignment_deg", "slide_roll_deg"):
            scen[name] = float(v)
        elif name.startswith("sim."):
            plant_over.append(f"{name[4:]}={_toml_value(v)}")
        elif name.startswith("controller."):
            ctl_over.append(f"{name[11:]}={_toml_value(v)}")
        elif name.startswith("scenario."):
            scen[name[9:]] = v
    if noise != 1.0:
        sensors = SensorParams()
        plant_over += [f"sensors.{f}={_toml_value(getattr(sensors, f) * noise)}" for f in _NOISE_FIELDS]
    sp = apply_overrides(base_sp, [f"{k}={_toml_value(v)}" for k, v in scen.items()]) if scen else base_sp
    faults = []
    window = _event_window(spec, sp)
    if params.get("mocap_dropout_s", 0.0) > 0.0:
        t = float(rng.uniform(*window))
        derived["mocap_dropout_t_s"] = t
        faults.append(MocapDropout(t, float(params["mocap_dropout_s"])))
    if params.get("gust_force_N", 0.0) > 0.0:
        t = float(rng.uniform(*window))
        az = float(rng.uniform(-math.pi, math.pi))
        derived["gust_t_s"] = t
        derived["gust_azimuth_deg"] = math.degrees(az)
        f = float(params["gust_force_N"])
        dur = float(params.get("gust_duration_s", 1.0))
        faults.append(WindGust(t, dur, (f * math.cos(az), f * math.sin(az), 0.0)))
    if params.get("failed_rotor", 0) > 0:
        t = float(rng.uniform(*window))
        derived["rotor_failure_t_s"] = t
        told = bool(params.get("rotor_failure_told", True))
        faults.append(RotorFailure(int(params["failed_rotor"]), t, told, ROTOR_DETECT_DELAY_S))
    plant = PlantPerturbation(
        mass_scale=mass,
        inertia_scale=(inertia, inertia, inertia),
        scene_offset_W=tuple(offset),
        sim_overrides=tuple(plant_over),
        faults=tuple(faults),
    )
    identify = spec.maps == "identify-truth" and o.map != "nominal"
    # "identify-truth" stands in for the file the worker identifies (execute_run); a nominal run loads no maps.
    maps = None if spec.maps == "none" or (spec.maps == "identify-truth" and not identify) else spec.maps
    options = ExperimentOptions(
        solver=o.solver,
        estimator=o.estimator,
        duration_s=o.duration_s,
        seed=derived["sim_seed"],
        truth=o.truth,
        vehicle=o.vehicle,
        controller_config=o.controller_config,
        overrides=tuple(ctl_over),
        map_mode=o.map,
        maps=maps,
        blend=o.blend,
        quick=o.quick,
        zero_observer=o.zero_observer,
        sim_overrides=o.sim_overrides,
        scenario=sp,
        plant=None if plant.is_identity else plant,
    )
    return RunJob(index, spec.task, options, params, derived, identify)


def _dry_run(spec: CampaignSpec) -> None:
    """Check the base options before any run: build run 0's options and the controller parameters."""
    job = run_options(spec, 0)
    job.options.controller_params()
    from omnirotor.vehicle import load_vehicle

    vehicle = load_vehicle(job.options.vehicle)
    if spec.maps not in ("none", "identify-truth"):
        job.options.load_maps(vehicle)
    if job.options.plant is not None:
        job.options.plant_sim_params()


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
    from omnirotor.experiments.scenarios import hover_attitudes
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


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def execute_run(job: RunJob) -> dict:
    """Run one job in this process and return its record (never raises for a failed run).

    The record: ``index``, ``status`` ("ok" or "error"), ``params``, ``derived``, ``success`` (the task's
    verdict, or None), ``metrics`` (the run's summary), ``error`` and ``elapsed_s``.
    """
    from omnirotor.experiments.closed_loop import run_task

    tic = time.perf_counter()
    record: dict[str, Any] = {"index": job.index, "params": job.params, "derived": job.derived}
    try:
        options = job.options
        with tempfile.TemporaryDirectory(prefix="omnirotor-campaign-") as tmp:
            if job.identify_truth:
                maps_path = Path(tmp) / "maps.json"
                identify_truth_maps(options, seed=job.derived["sim_seed"]).save(maps_path)
                options = dataclasses.replace(options, maps=str(maps_path))
            summary = run_task(job.task, options).summary()
        summary.pop("figure", None)
        record.update(status="ok", success=summary.get("success"), metrics=summary, error=None)
    except Exception as exc:  # a campaign records a failed run and goes on
        kind = "input" if isinstance(exc, InputError) else type(exc).__name__
        where = "" if isinstance(exc, InputError) else " at " + traceback.extract_tb(exc.__traceback__)[-1].name
        record.update(status="error", success=None, metrics=None, error=f"{kind}: {exc}{where}")
    record["elapsed_s"] = time.perf_counter() - tic
    return _jsonable(record)


# -- the results file --------------------------------------------------------------------------------------------


def load_results(out_dir: str | Path, repair: bool = False) -> dict[int, dict]:
    """The records of ``DIR/results.jsonl`` by run index (the last record of an index wins).

    A last line without its newline is what a killed campaign leaves: it is ignored (and cut off with
    ``repair``). Any other unreadable line is an :class:`InputError`.
    """
    path = Path(out_dir) / _RESULTS
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        return {}
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    end = raw.rfind(b"\n") + 1
    if end < len(raw) and repair:
        with path.open("r+b") as fh:
            fh.truncate(end)
    out: dict[int, dict] = {}
    for n, line in enumerate(raw[:end].splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise InputError(f"{path}: line {n} is not valid JSON (fix it or start again with --restart)") from None
        idx = rec.get("index") if isinstance(rec, dict) else None
        if isinstance(idx, bool) or not isinstance(idx, int) or idx < 0:
            raise InputError(f"{path}: line {n} has no run index (fix it or start again with --restart)")
        out[idx] = rec
    return out


def _append_record(path: Path, record: dict) -> None:
    """Append one JSON line with a single write, flushed to disk."""
    line = (json.dumps(record, separators=(",", ":"), allow_nan=False) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line)
        os.fsync(fd)
    finally:
        os.close(fd)


def _prepare_folder(spec: CampaignSpec, out: Path, restart: bool) -> None:
    """Create or check the campaign folder (refuses another campaign's folder unless restarting)."""
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    definition_path = out / _DEFINITION
    digest = spec.digest()
    if definition_path.exists() and not restart:
        try:
            stored = json.loads(definition_path.read_text())
            old_digest, old_def = stored["hash"], stored["definition"]
        except (OSError, ValueError, KeyError, TypeError):
            raise InputError(f"{definition_path}: unreadable campaign definition (use --restart)") from None
        if old_digest != digest:
            new_def = spec.definition()
            changed = sorted(k for k in set(old_def) | set(new_def) if old_def.get(k) != new_def.get(k))
            raise InputError(
                f"{out} holds another campaign (hash {old_digest[:12]}, this one {digest[:12]}; changed: "
                f"{', '.join(changed) or 'definition'}); use --restart to discard its results, or another --out"
            )
        return
    if not definition_path.exists() and (out / _RESULTS).exists() and not restart:
        raise InputError(f"{out} has results but no {_DEFINITION}; use --restart to discard them")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out {out}: cannot create ({exc.strerror})") from None
    if restart:
        for name in (_RESULTS, _SUMMARY):
            (out / name).unlink(missing_ok=True)
        plots = out / _PLOTS
        if plots.is_dir():
            for p in plots.glob("success-vs-*.png"):
                p.unlink()
    write_json_atomic(definition_path, {"hash": digest, "source": spec.source, "definition": spec.definition()})


# -- running -----------------------------------------------------------------------------------------------------


def _local_backend(jobs: list[RunJob], workers: int):
    """Yield records as the runs finish, on a process pool (one worker: in this process, in order)."""
    if workers == 1:
        for job in jobs:
            yield execute_run(job)
        return
    pool = cf.ProcessPoolExecutor(max_workers=workers)
    try:
        futures = [pool.submit(execute_run, job) for job in jobs]
        for fut in cf.as_completed(futures):
            yield fut.result()
    finally:
        pool.shutdown(wait=False, cancel_futures=True)


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
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
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
    _prepare_folder(spec, out, restart)
    done = {i: r for i, r in load_results(out, repair=True).items() if i < n}
    todo = [i for i in range(n) if i not in done]
    report = progress or (lambda k, total, rec: None)
    report(len(done), n, None)
    jobs = []
    for i in todo:
        try:
            jobs.append(run_options(spec, i))
        except InputError as exc:  # this draw is invalid: record it as a failed run
            rec = _jsonable({"index": i, "status": "error", "params": {}, "derived": {}, "success": None,
                             "metrics": None, "error": f"input: {exc}", "elapsed_s": 0.0})  # fmt: skip
            _append_record(out / _RESULTS, rec)
            done[i] = rec
    count = len(done)
    report(count, n, None)
    if jobs:
        if backend == "local":
            stream = _local_backend(jobs, workers or min(len(jobs), os.cpu_count() or 1))
        else:
            stream = _ray_backend(ray, jobs, workers)
        for rec in stream:
            _append_record(out / _RESULTS, rec)
            done[rec["index"]] = rec
            count += 1
            report(count, n, rec)
    summary = summarize(spec, [done[i] for i in sorted(done)], n)
    summary["executed"] = len(jobs)
    if plots:
        summary["plots"] = [str(p) for p in plot_campaign(spec, [done[i] for i in sorted(done)], out / _PLOTS)]
    write_json_atomic(out / _SUMMARY, summary)
    return summary


# -- summary -----------------------------------------------------------------------------------------------------


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float] | None:
    """The 95 % Wilson score interval of a success rate (None when n = 0)."""
    if n == 0:
        return None
    p = successes / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    # the interval always holds p; rounding could put an end a hair past it at p = 0 or 1
    return (min(p, max(0.0, centre - half)), max(p, min(1.0, centre + half)))


def _flatten(obj: Any, prefix: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    if isinstance(obj, dict):
        for k, v in obj.items():
            out.update(_flatten(v, f"{prefix}{k}."))
    elif isinstance(obj, list) and all(_is_number(v) for v in obj) and len(obj) <= 8:
        for i, v in enumerate(obj):
            out[f"{prefix}{'xyzabcde'[i] if len(obj) == 3 else i}"] = float(v)
    elif _is_number(obj):
        out[prefix[:-1]] = float(obj)
    return out


def metric_value(record: dict, metric: str) -> float | None:
    """The value of a dotted metric in a run record (None when absent)."""
    if record.get("metrics") is None:
        return None
    return _flatten(record["metrics"]).get(metric)


def _bins(values: list[Any], k: int) -> list[tuple[Any, Any]]:
    nums = [v for v in values if _is_number(v)]
    if len(nums) != len(values) or len(set(nums)) <= k:
        return [(v, v) for v in sorted(set(values), key=lambda x: (str(type(x)), x))]
    lo, hi = min(nums), max(nums)
    edges = np.linspace(lo, hi, k + 1)
    return [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _in_bin(v: Any, b: tuple[Any, Any], last: bool) -> bool:
    if b[0] == b[1] or not _is_number(v):
        return v == b[0]
    return b[0] <= v < b[1] or (last and v == b[1])


def binned_success(records: list[dict], param: str, k: int) -> list[dict]:
    """Success rate of the runs with a verdict per bin of a parameter (numbers: k equal bins; else per value)."""
    rows = [
        (r["params"][param], bool(r["success"]))
        for r in records
        if r.get("success") is not None and param in r.get("params", {})
    ]
    if not rows:
        return []
    bins = _bins([v for v, _ in rows], k)
    out = []
    for j, b in enumerate(bins):
        hits = [s for v, s in rows if _in_bin(v, b, j == len(bins) - 1)]
        ci = wilson_interval(sum(hits), len(hits))
        out.append(
            {
                "low": b[0],
                "high": b[1],
                "runs": len(hits),
                "successes": int(sum(hits)),
                "rate": sum(hits) / len(hits) if hits else None,
                "ci95": list(ci) if ci else None,
            }
        )
    return out


def summarize(spec: CampaignSpec, records: list[dict], runs: int) -> dict:
    """The campaign's summary: counts, success rate, metric distributions, binned success per parameter."""
    ok = [r for r in records if r.get("status") == "ok"]
    judged = [r for r in ok if r.get("success") is not None]
    wins = sum(bool(r["success"]) for r in judged)
    ci = wilson_interval(wins, len(judged))
    flat = [_flatten(r["metrics"]) for r in ok]
    keys = sorted({k for f in flat for k in f})
    metrics = {}
    for k in keys:
        v = np.array([f[k] for f in flat if k in f])
        metrics[k] = {
            "n": int(v.size),
            "mean": float(v.mean()),
            "std": float(v.std()),
            "min": float(v.min()),
            "p5": float(np.percentile(v, 5)),
            "median": float(np.median(v)),
            "p95": float(np.percentile(v, 95)),
            "max": float(v.max()),
        }
    unsafe = [r["index"] for r in ok if not r["metrics"].get("safety", {}).get("commands_within_limits", True)]
    return _jsonable(
        {
            "task": spec.task,
            "hash": spec.digest(),
            "runs_requested": runs,
            "runs_done": len(records),
            "runs_ok": len(ok),
            "runs_error": len(records) - len(ok),
            "errors": {str(r["index"]): r.get("error") for r in records if r.get("status") != "ok"},
            "runs_judged": len(judged),
            "successes": wins,
            "success_rate": wins / len(judged) if judged else None,
            "success_rate_ci95": list(ci) if ci else None,
            "runs_with_unsafe_commands": unsafe,
            "key_metric": spec.key_metric,
            "metrics": metrics,
            "parameters": {name: binned_success(ok, name, spec.bins) for name, _ in spec.vary},
        }
    )


# -- plots -------------------------------------------------------------------------------------------------------


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    from omnirotor.experiments.figures import save_figure

    return save_figure(fig, path)


def _draw_success(ax, bins: list[dict], label: str | None = None, color: str = "#2c3e50") -> None:
    rows = [b for b in bins if b["runs"]]
    if not rows:
        return
    numeric = all(_is_number(b["low"]) for b in rows)
    x = [0.5 * (b["low"] + b["high"]) if numeric else str(b["low"]) for b in rows]
    y = [b["rate"] for b in rows]
    lo = [b["rate"] - b["ci95"][0] for b in rows]
    hi = [b["ci95"][1] - b["rate"] for b in rows]
    ax.errorbar(x, y, yerr=[lo, hi], marker="o", capsize=3, color=color, label=label)
    for xi, b in zip(x, rows, strict=True):
        ax.annotate(f"{b['successes']}/{b['runs']}", (xi, b["rate"]), textcoords="offset points", xytext=(4, 6),
                    fontsize=7, color=color)  # fmt: skip
    ax.set_ylim(-0.05, 1.12)
    ax.set_ylabel("success rate (95 % CI)")
    ax.grid(alpha=0.3)


def _scatter(ax, records: list[dict], param: str, metric: str, color: str | None = None, label: str | None = None):
    pts = [(r["params"].get(param), metric_value(r, metric), r.get("success")) for r in records]
    pts = [(x, y, s) for x, y, s in pts if x is not None and y is not None]
    if not pts:
        return
    if color is None:
        for flag, c, lab in ((True, "#27ae60", "success"), (False, "#c0392b", "failure"), (None, "0.5", "no verdict")):
            sel = [(x, y) for x, y, s in pts if s is flag]
            if sel:
                ax.scatter(*zip(*sel, strict=True), s=16, color=c, label=lab, alpha=0.8)
    else:
        ok = [(x, y) for x, y, s in pts if s is not False]
        bad = [(x, y) for x, y, s in pts if s is False]
        if ok:
            ax.scatter(*zip(*ok, strict=True), s=16, color=color, alpha=0.8, label=f"{label} success")
        if bad:
            ax.scatter(*zip(*bad, strict=True), s=22, color=color, marker="x", label=f"{label} failure")
    ax.set_ylabel(metric)
    ax.grid(alpha=0.3)


def _unit(param: str) -> str:
    p = PARAMETERS.get(param)
    return f"{param} [{p.unit}]" if p is not None and p.unit else param


def plot_campaign(spec: CampaignSpec, records: list[dict], out_dir: str | Path) -> list[Path]:
    """One PNG per varied parameter: binned success rate, and the key metric of each run against it."""
    plt = _plt()
    ok = [r for r in records if r.get("status") == "ok"]
    paths = []
    for name, _ in spec.vary:
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
        _draw_success(a1, binned_success(ok, name, spec.bins))
        a1.set_xlabel(_unit(name))
        a1.set_title(f"{spec.task}: success against {name}")
        _scatter(a2, ok, name, spec.key_metric)
        a2.set_xlabel(_unit(name))
        a2.set_title(f"{spec.key_metric} of each run")
        if a2.has_data():
            a2.legend(fontsize=8)
        paths.append(_save(fig, Path(out_dir) / f"success-vs-{name.replace('.', '_')}.png"))
    return paths


def _load_folder(folder: str | Path) -> tuple[dict, list[dict]]:
    path = Path(folder) / _DEFINITION
    try:
        stored = json.loads(path.read_text())
        definition = stored["definition"]
    except FileNotFoundError:
        raise InputError(f"{folder}: not a campaign folder (no {_DEFINITION})") from None
    except (OSError, ValueError, KeyError, TypeError):
        raise InputError(f"{path}: unreadable campaign definition") from None
    return definition, [r for r in load_results(folder).values() if r.get("status") == "ok"]


def plot_comparison(
    folders: list[str | Path], param: str, out: str | Path, labels: list[str] | None = None, bins: int = 6
) -> Path:
    """Success rate (and the key metric) against one parameter for several campaigns on shared bins.

    Args:
        folders: campaign folders.
        param: the varied parameter to plot against.
        out: PNG file.
        labels: legend labels (default: each campaign's map and folder name).
        bins: number of equal bins over the union of the drawn values.

    Raises:
        InputError: a folder is not a campaign, or does not vary ``param``.
    """
    if not str(out).lower().endswith(".png"):
        raise InputError(f"{out}: the output must be a .png file")
    if labels is not None and len(labels) != len(folders):
        raise InputError(f"{len(labels)} labels for {len(folders)} campaigns")
    loaded = [_load_folder(f) for f in folders]
    for f, (definition, _) in zip(folders, loaded, strict=True):
        if param not in definition.get("vary", {}):
            raise InputError(f"{f}: the campaign does not vary {param!r}")
    values = [r["params"][param] for _, recs in loaded for r in recs if param in r["params"]]
    if not values:
        raise InputError(f"no finished runs to plot in {', '.join(map(str, folders))}")
    edges = _bins(values, bins)
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    colors = ("#c0392b", "#27ae60", "#2980b9", "#8e44ad", "#d35400")
    task = loaded[0][0].get("task", "")
    metric = KEY_METRICS.get(task, "ee_rms_error.x_cm")
    for j, (folder, (definition, recs)) in enumerate(zip(folders, loaded, strict=True)):
        label = labels[j] if labels else f"{definition['options']['map']} map ({Path(folder).name})"
        color = colors[j % len(colors)]
        rows = []
        judged = [(r["params"][param], bool(r["success"])) for r in recs if r.get("success") is not None]
        for i, b in enumerate(edges):
            hits = [s for v, s in judged if _in_bin(v, b, i == len(edges) - 1)]
            ci = wilson_interval(sum(hits), len(hits))
            rows.append({"low": b[0], "high": b[1], "runs": len(hits), "successes": sum(hits),
                         "rate": sum(hits) / len(hits) if hits else None, "ci95": ci})  # fmt: skip
        _draw_success(a1, rows, label=label, color=color)
        _scatter(a2, recs, param, metric, color=color, label=label)
    a1.set_xlabel(_unit(param))
    a1.set_title(f"{task}: success rate against {param}")
    a1.legend(fontsize=8, loc="lower left")
    a2.set_xlabel(_unit(param))
    a2.set_title(f"{metric} of each run")
    a2.legend(fontsize=8)
    return _save(fig, Path(out))
