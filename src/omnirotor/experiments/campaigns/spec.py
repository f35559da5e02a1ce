"""Campaign definitions: the varied parameters, their distributions, the file, and each run's options.

The file format, the parameters and the seeding are documented in :mod:`omnirotor.experiments.campaigns.runner`;
this module reads a campaign file into a :class:`CampaignSpec` (every mistake an
:class:`~omnirotor.errors.InputError`) and turns run ``i`` into its options (:func:`run_options`). The
parameters are a table (:data:`PARAMETERS`): each carries its target (the plant, the controller, the scenario
knobs of SPEC §5.2, or a timed fault) and a typed ``apply`` that puts a drawn value into the run being built
(:class:`RunDraft`); the values reach a :class:`~omnirotor.experiments.faults.PlantPerturbation` and the
options as typed ``(key, value)`` pairs (:func:`omnirotor.config.apply_values`), never as text parsed back.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Callable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from omnirotor.config import apply_values, from_mapping, load_toml
from omnirotor.errors import InputError
from omnirotor.experiments.faults import MocapDropout, PlantPerturbation, RotorFailure, WindGust
from omnirotor.experiments.loop import HOVER_DURATION_S
from omnirotor.experiments.tasks.common import CONTACT_TASKS, HOVER_TASKS, MAP_MODES, ExperimentOptions
from omnirotor.experiments.tasks.scenarios import ScenarioParams
from omnirotor.limits import MAX_CAMPAIGN_RUNS, MAX_SEED
from omnirotor.safe_io import check_input_file
from omnirotor.sim.params import SensorParams, SimParams

__all__ = [
    "CampaignOptions",
    "CampaignSpec",
    "Distribution",
    "Parameter",
    "RunJob",
    "PARAMETERS",
    "CAMPAIGN_TASKS",
    "KEY_METRICS",
    "DISTRIBUTIONS",
    "load_campaign",
    "campaign_from_mapping",
    "campaign_preset_names",
    "run_options",
    "expected_duration_s",
]

CAMPAIGN_TASKS = CONTACT_TASKS + HOVER_TASKS + ("hover",)
"""Tasks a campaign can run: the experiment tasks, which fly the perturbed plant."""
KEY_METRICS = {
    "sliding": "contact.fraction",
    "peg-in-hole": "insertion.max_depth_m",
    "point-contact": "normal_force.true_mean_N",
    "point-contact-tilted": "normal_force.true_mean_N",
    "identify-flights": "ee_rms_error.z_cm",
    "hover-validation": "ee_rms_error.z_cm",
    "hover": "ee_rms_error.z_cm",
}
"""Default metric of the scatter plots, per task (dotted path into the run's summary)."""
DISTRIBUTIONS = {
    "uniform": ({"low", "high"}, set()),
    "loguniform": ({"low", "high"}, set()),
    "normal": ({"std"}, {"mean", "low", "high"}),
    "choice": ({"values"}, {"weights"}),
    "constant": ({"value"}, set()),
}
"""Required and optional keys of each distribution."""
HOVER_EVENT_WINDOW_S = (2.0, 8.0)
"""Timed events of the hover tasks start in this window [s] (clipped to end by 75 % of a shorter ``hover`` run)."""
ROTOR_DETECT_DELAY_S = 0.02
"""Time from a rotor failure to the controller being told in campaigns [s] (ESC telemetry, [A])."""
_SEED_MAX = 2**31 - 1


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
        target: what it changes: "plant" (the true vehicle, scene or simulator), "controller", "scenario" (the
            task's protocol) or "fault" (a timed fault of the run, scheduled by :func:`run_options`).
        apply: how a drawn value goes into the run being built (``apply(draft, value)``, :class:`RunDraft`);
            None for the faults.
    """

    name: str
    help: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    tasks: tuple[str, ...] | None = None
    kind: str = "float"
    needs_ukf: bool = False
    target: str = "plant"
    apply: Callable[[RunDraft, Any], None] | None = None


@dataclasses.dataclass
class RunDraft:
    """A run's options while :func:`run_options` builds them from the drawn values (typed values, no text).

    Attributes:
        derived: the run's derived seeds (``rotor_error_seed``, ...).
        mass_scale: true mass over the believed one.
        inertia_scale: true inertia over the believed one (every axis).
        scene_offset_W: the true scene's displacement [m].
        noise_scale: every sensor noise level multiplied by this.
        sim: ``(dotted key, value)`` of the plant's simulator parameters, in order.
        controller: ``(dotted key, value)`` of the controller parameters, in order.
        scenario: the task's protocol knobs (``ScenarioParams`` fields).
    """

    derived: dict[str, Any]
    mass_scale: float = 1.0
    inertia_scale: float = 1.0
    scene_offset_W: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 0.0])
    noise_scale: float = 1.0
    sim: list[tuple[str, Any]] = dataclasses.field(default_factory=list)
    controller: list[tuple[str, Any]] = dataclasses.field(default_factory=list)
    scenario: dict[str, Any] = dataclasses.field(default_factory=dict)


def _scale(field: str) -> Callable[[RunDraft, Any], None]:
    """A relative error ``e`` of the plant: ``field = 1 + e``."""

    def apply(d: RunDraft, v: Any) -> None:
        setattr(d, field, 1.0 + v)

    return apply


def _noise(d: RunDraft, v: Any) -> None:
    d.noise_scale = float(v)


def _sim(key: str, model: str | None = None, seeded: bool = False) -> Callable[[RunDraft, Any], None]:
    """Set the plant's simulator parameter ``key``.

    ``model``: and the truth model it belongs to; ``seeded``: and the run's rotor-error seed.
    """

    def apply(d: RunDraft, v: Any) -> None:
        d.sim.append((key, float(v)))
        if model is not None:
            d.sim.append(("aero.model", model))
        if seeded:
            d.sim.append(("aero.error_seed", d.derived["rotor_error_seed"]))

    return apply


def _offset(axis: int) -> Callable[[RunDraft, Any], None]:
    def apply(d: RunDraft, v: Any) -> None:
        d.scene_offset_W[axis] = float(v)

    return apply


def _scenario(field: str) -> Callable[[RunDraft, Any], None]:
    def apply(d: RunDraft, v: Any) -> None:
        d.scenario[field] = float(v)

    return apply


_P = Parameter
PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        _P("mass_error", "relative error of the true mass: m_true = m (1 + e)", "", -0.9, 10.0,
           apply=_scale("mass_scale")),
        _P("inertia_error", "relative error of the true inertia (every axis): J_true = J (1 + e)", "", -0.9, 10.0,
           apply=_scale("inertia_scale")),
        _P("gamma", "inflow sensitivity of SPEC §7's truth model (4; makes SPEC §7 the truth)", "", 0.0,
           apply=_sim("aero.gamma", model="spec7")),
        _P("kappa0", "isolated-rotor thrust gain of SPEC §7's truth model (1.18; makes SPEC §7 the truth)", "", 1e-3,
           apply=_sim("aero.kappa0", model="spec7")),
        _P("rotor_gain_error_std", "per-rotor relative thrust-gain error, standard deviation", "", 0.0, 0.5,
           apply=_sim("aero.gain_error_std", seeded=True)),
        _P("rotor_tilt_error_std_deg", "per-rotor axis tilt error, standard deviation", "deg", 0.0, 30.0,
           apply=_sim("aero.tilt_error_std_deg", seeded=True)),
        _P("scene_offset_x", "true scene displaced along world x from the planned one", "m", tasks=CONTACT_TASKS,
           apply=_offset(0)),
        _P("scene_offset_y", "true scene displaced along world y from the planned one", "m", tasks=CONTACT_TASKS,
           apply=_offset(1)),
        _P("scene_offset_z", "true scene displaced along world z from the planned one", "m", tasks=CONTACT_TASKS,
           apply=_offset(2)),
        _P("friction", "sliding friction coefficient of every contact", "", 0.0, tasks=CONTACT_TASKS,
           apply=_sim("scene.friction")),
        _P("sensor_noise_scale", "every sensor noise level multiplied by this", "", 0.0, apply=_noise),
        _P("mocap_latency_s", "motion-capture latency", "s", 0.0, 0.2, needs_ukf=True,
           apply=_sim("sensors.mocap_latency_s")),
        _P("mocap_dropout_s", "length of one motion-capture dropout (0 = none)", "s", 0.0, needs_ukf=True,
           target="fault"),
        _P("gust_force_N", "peak force of one horizontal 1-cos gust at the CoM (0 = none)", "N", 0.0, target="fault"),
        _P("gust_duration_s", "length of the gust", "s", 1e-3, target="fault"),
        _P("failed_rotor", "rotor that stops (numbered from 1; 0 = none)", "", 0, kind="int", target="fault"),
        _P("rotor_failure_told", "whether the controller is told of the failed rotor", "", kind="bool",
           target="fault"),
        _P("peg_misalignment_deg", "approach roll misalignment of the peg", "deg", -60.0, 60.0, ("peg-in-hole",),
           target="scenario", apply=_scenario("peg_misalignment_deg")),
        _P("slide_roll_deg", "roll at the apex of the pipe", "deg", 0.0, 80.0, ("sliding",),
           target="scenario", apply=_scenario("slide_roll_deg")),
    )
}  # fmt: skip
"""The named parameters, each with its target and how it applies; ``sim.<key>``, ``controller.<key>`` and
``scenario.<field>`` are accepted too (:func:`_parameter`)."""
_GENERIC_PREFIXES = ("sim.", "controller.", "scenario.")
_NOISE_FIELDS = tuple(
    f.name for f in dataclasses.fields(SensorParams) if f.name.endswith("_std") or f.name.endswith("_std_hz")
)


def _parameter(name: str) -> Parameter:
    if name in PARAMETERS:
        return PARAMETERS[name]
    if name.startswith(_GENERIC_PREFIXES) and len(name.split(".", 1)[1]) > 0:
        group, key = name.split(".", 1)
        target = {"sim": "plant", "controller": "controller", "scenario": "scenario"}[group]
        return Parameter(name, "generic value", kind="any", target=target, apply=_generic(group, key))
    raise InputError(
        f"unknown parameter {name!r}; parameters: {', '.join(PARAMETERS)}, or sim.<key>, controller.<key>, "
        "scenario.<field>"
    )


def _generic(group: str, key: str) -> Callable[[RunDraft, Any], None]:
    """The apply of ``sim.<key>``, ``controller.<key>`` or ``scenario.<field>``: the drawn value as it is."""

    def apply(d: RunDraft, v: Any) -> None:
        if group == "sim":
            d.sim.append((key, v))
        elif group == "controller":
            d.controller.append((key, v))
        else:
            d.scenario[key] = v

    return apply


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
        solver: allocation QP backend, "active-set" (default), "daqp" or "proxsuite".
        truth: truth aerodynamics, "wake" (default), "spec7" / "interference" or "nominal".
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
    solver: str = "active-set"
    truth: str = "wake"
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
        if not path.suffix and not os.path.lexists(path) and len(os.fsencode(path.name)) <= 255:
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
            raise InputError(f"{where}: {key} must be {'an integer' if tp is int else 'a string'}, got {v!r:.40}")
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
    seed = scalars["seed"]
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise InputError(f"{where}: seed must be an integer >= 0 and < 2^63")
    if not 1 <= scalars["runs"] <= MAX_CAMPAIGN_RUNS:
        raise InputError(f"{where}: runs must lie in 1..{MAX_CAMPAIGN_RUNS} (omnirotor.limits)")
    if not 1 <= scalars["bins"] <= 50:
        raise InputError(f"{where}: bins must be in 1..50, got {scalars['bins']}")
    maps = scalars["maps"]
    if maps not in ("none", "identify-truth"):
        check_input_file(maps, "maps (a file, or 'identify-truth' or 'none')")
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
    varied = {n for n, _ in vary}
    for extra, main in (("gust_duration_s", "gust_force_N"), ("rotor_failure_told", "failed_rotor")):
        if extra in varied and main not in varied:
            raise InputError(f"{where}: vary.{extra} does nothing without vary.{main}")
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


def _check_generic(name: str, value: Any, where: str) -> None:
    group, key = name.split(".", 1)
    try:
        if group == "sim":
            apply_values(SimParams(), [(key, value)])
        elif group == "controller":
            from omnirotor.control.controller import ControllerParams

            apply_values(ControllerParams(), [(key, value)])
        else:
            apply_values(ScenarioParams(), [(key, value)])
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


def _scenario_builder(task: str):
    """The builder of a contact task's scenario (:mod:`omnirotor.experiments.tasks.scenarios`)."""
    from omnirotor.experiments.tasks import scenarios

    return {
        "point-contact": scenarios.point_contact,
        "point-contact-tilted": scenarios.point_contact_tilted,
        "sliding": scenarios.sliding,
        "peg-in-hole": scenarios.peg_in_hole,
    }[task]


def expected_duration_s(job: RunJob) -> float | None:
    """The simulated length of a job's run [s], as its task will fly it; None when the task decides alone.

    Used to send the longest runs first (a campaign's runs differ in length when it varies the scenario), so that
    no worker is left stepping a long run alone at the end. The run itself never depends on it.
    """
    o = job.options
    if o.duration_s is not None:
        return float(o.duration_s)
    if job.task == "hover":
        return HOVER_DURATION_S
    if job.task in CONTACT_TASKS:
        from omnirotor.experiments.tasks.common import _scenario_params  # the task's own choice of protocol

        return _scenario_builder(job.task)(o.sim_params().scene, _scenario_params(o), quick=o.quick).duration_s
    return None


def _event_window(spec: CampaignSpec, sp: ScenarioParams) -> tuple[float, float]:
    if spec.task in CONTACT_TASKS:
        t0, t1 = _scenario_builder(spec.task)(SimParams().scene, sp, quick=spec.options.quick).contact_phase
    else:
        t0, t1 = HOVER_EVENT_WINDOW_S
    d = spec.options.duration_s
    if spec.task == "hover":  # the window must fit its short default length too
        d = d if d is not None else HOVER_DURATION_S
    if d is not None and (spec.task in CONTACT_TASKS or spec.task == "hover") and t1 > 0.75 * d:
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
    draft = RunDraft(derived, scenario=dict(spec.scenario))
    for name, v in params.items():
        apply = _parameter(name).apply
        if apply is not None:  # the faults are scheduled below
            apply(draft, v)
    plant_values = list(draft.sim)
    if draft.noise_scale != 1.0:
        sensors = SensorParams()
        plant_values += [(f"sensors.{f}", getattr(sensors, f) * draft.noise_scale) for f in _NOISE_FIELDS]
    sp = apply_values(base_sp, draft.scenario.items()) if draft.scenario else base_sp
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
    inertia = draft.inertia_scale
    plant = PlantPerturbation(
        mass_scale=draft.mass_scale,
        inertia_scale=(inertia, inertia, inertia),
        scene_offset_W=tuple(draft.scene_offset_W),
        sim_values=tuple(plant_values),
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
        overrides=tuple(o.controller_overrides),
        controller_values=tuple(draft.controller),
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
    for pname, dist in spec.vary:
        if pname == "failed_rotor":
            beyond = [v for v in dist.support() if v > vehicle.n_rotors]
            if beyond:
                raise InputError(
                    f"{spec.source} vary.failed_rotor: rotor {beyond[0]} does not exist; the vehicle "
                    f"{vehicle.name!r} has rotors 1..{vehicle.n_rotors} (0 = none)"
                )
    if spec.maps not in ("none", "identify-truth"):
        job.options.load_maps(vehicle)
    if job.options.plant is not None:
        job.options.plant_sim_params()
