"""The manual's Reference pages, generated from the code each time the manual is built.

An MkDocs hook (mkdocs.yml ``hooks:``): ``on_files`` adds the pages below as generated
files, so they are never written into docs/ and cannot drift from the code:

* reference/configuration.md: every key of the pydantic models in app/config, with its
  type, default, unit (from the name's suffix), bounds and docstring;
* reference/cli.md: every command and option of the argparse parser of app/cli.py;
* reference/rest.md: every path and operation of the app's OpenAPI document;
* reference/metrics.md: the fields of metrics.json (app/campaign/sweep.py METRIC_FIELDS);
* reference/telemetry.md: the columns of telemetry.csv (app/sim/telemetry.py);
* reference/bag.md: the ROS 2 bag's topics and message types (read from app/runs/bag.py);
* reference/scenarios.md: the scenario library, app/scenarios/*.toml.

A field, column or topic the tables here do not describe fails the build (a warning,
which ``mkdocs build --strict`` makes an error): add its line below.
"""

from __future__ import annotations

import argparse
import ast
import logging
import re
import sys
import types
import typing
from pathlib import Path

from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.plugins.orbit_reference")
ROOT = Path(__file__).resolve().parent.parent

UNITS = (  # name suffix -> unit, longest first where one ends another
    ("_Nmprad", "N·m/rad"), ("_Nm_per_rad", "N·m/rad"), ("_sprad", "s/rad"),
    ("_kgm2", "kg·m²"), ("_mps2", "m/s²"),
    ("_radps2", "rad/s²"), ("_radps", "rad/s"), ("_mps", "m/s"), ("_Npm", "N/m"),
    ("_spm", "s/m"), ("_Nm", "N·m"), ("_Ns", "N·s"), ("_N", "N"), ("_kg", "kg"),
    ("_m", "m"), ("_s", "s"), ("_hz", "Hz"), ("_rad", "rad"), ("_deg", "°"), ("_J", "J"),
    ("_us", "µs"), ("_MiB", "MiB"), ("_cycles", "cycles"),
)


def unit_of(name: str) -> str:
    """The unit a name's suffix states (the project's convention: force_N, dt_s), or ''."""
    for suffix, unit in UNITS:
        if name.endswith(suffix):
            return unit
    return ""


# --- configuration ---------------------------------------------------------------------


def _is_model(tp) -> bool:
    from pydantic import BaseModel

    return isinstance(tp, type) and issubclass(tp, BaseModel)


def _strip(tp):
    """The type inside Annotated[...]."""
    while typing.get_origin(tp) is typing.Annotated:
        tp = typing.get_args(tp)[0]
    return tp


def _type_text(tp) -> str:
    tp = _strip(tp)
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is typing.Literal:
        return " | ".join(repr(a).replace("'", '"') for a in args)
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_text(a) for a in args)
    if origin is tuple:
        return f"[{', '.join(_type_text(a) for a in args)}]"
    if origin is list:
        return f"list of {_type_text(args[0])}"
    if origin is dict:
        return f"table of {_type_text(args[1])}"
    if tp is type(None):
        return "none"
    if _is_model(tp):
        return f"[{tp.__name__}](#{tp.__name__.lower()})"
    return getattr(tp, "__name__", str(tp)).replace("StrictBool", "bool")


def _bounds(tp, metadata) -> str:
    """Bounds from the field's constraints and those of the types it is made of."""
    found: list[str] = []

    def take(meta):
        for m in meta:
            for attr, sign in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤"),
                               ("min_length", "length ≥"), ("max_length", "length ≤")):
                value = getattr(m, attr, None)
                if value is not None and not callable(value):
                    text = f"{sign} {value:g}" if isinstance(value, (int, float)) \
                        else f"{sign} {value}"
                    if text not in found:
                        found.append(text)
            take(getattr(m, "metadata", ()) or ())

    def walk(t):
        if typing.get_origin(t) is typing.Annotated:
            args = typing.get_args(t)
            take(args[1:])
            walk(args[0])
            return
        for a in typing.get_args(t):
            if not isinstance(a, (str, int, float)):
                walk(a)

    take(metadata)
    walk(tp)
    return ", ".join(found)


def _default_text(field) -> str:
    from pydantic import BaseModel
    from pydantic_core import PydanticUndefined

    if field.default is PydanticUndefined:
        return "*required*" if field.default_factory is None else "(computed)"
    value = field.default
    if isinstance(value, BaseModel):
        return "(table)"
    if isinstance(value, dict):
        return ", ".join(value) if value else "{}"
    if isinstance(value, list):
        return "[]" if not value else f"{len(value)} item(s)"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, tuple):
        return "[" + ", ".join(f"{v:.6g}" if isinstance(v, float) else str(v)
                               for v in value) + "]"
    if value is None:
        return "none"
    return str(value)


def _cell(text: str) -> str:
    """One table cell: one line, its bars escaped, no HTML (``<token>`` stays text)."""
    text = " ".join((text or "").split()).replace("|", "\\|")
    return text.replace("<", "&lt;").replace(">", "&gt;")


def _children(tp) -> list[tuple[str, type]]:
    """(path suffix, model) of the models a field holds: a table, an optional one, an
    array of tables (``.<i>``) or a table of tables (``.<name>``)."""
    tp = _strip(tp)
    origin = typing.get_origin(tp)
    if _is_model(tp):
        return [("", tp)]
    if origin in (typing.Union, types.UnionType):
        return [c for a in typing.get_args(tp) for c in _children(a)]
    if origin is list and _is_model(_strip(typing.get_args(tp)[0])):
        return [(".<i>", _strip(typing.get_args(tp)[0]))]
    if origin is dict and _is_model(_strip(typing.get_args(tp)[1])):
        return [(".<name>", _strip(typing.get_args(tp)[1]))]
    return []


def config_keys(model=None, prefix: str = "") -> list[tuple[str, type, str, object]]:
    """Every key of the configuration models, depth first: (dotted path, the model that
    holds it, the key, its FieldInfo). Table keys come with their own keys after them."""
    if model is None:
        from app.config import EmulatorConfig

        model = EmulatorConfig
    rows = []
    for name, field in model.model_fields.items():
        path = f"{prefix}{name}"
        rows.append((path, model, name, field))
        for suffix, child in _children(field.annotation):
            rows.extend(config_keys(child, f"{path}{suffix}."))
    return rows


def _model_doc(model) -> str:
    import inspect

    return inspect.cleandoc(model.__doc__ or "")


def configuration_page() -> str:
    from app.config import EmulatorConfig

    out = ["# Configuration keys", "",
           "Every key a scenario file, `--set KEY=VALUE`, a sweep's `[set]`/`[grid]` or a "
           "REST start body may give, generated from the pydantic models in "
           "`app/config/__init__.py` when this manual was built. Units follow the name's "
           "suffix (`_m` metres, `_s` seconds, `_N` newtons, `_Npm` N/m, …); an array of "
           "tables is written `satellites.<i>` (0-based with `--set`), a table of tables "
           "`materials.<name>`. A value out of bounds is refused with a message naming the "
           "key, before anything runs.", ""]
    groups: dict[str, list] = {}
    owners: dict[str, type] = {}
    for path, model, name, field in config_keys():
        table = path.rsplit(".", 1)[0] if "." in path else ""
        groups.setdefault(table, []).append((path, name, field))
        owners[table] = model
    for table, keys in groups.items():
        model = owners[table]
        title = f"`[{table}]`" if table else "Top level"
        out += [f"## {title}", "", f'<a id="{model.__name__.lower()}"></a>'
                if table and not _first_use(groups, owners, table) else "", ""]
        doc = _model_doc(model) if model is not EmulatorConfig else _model_doc(model)
        if doc:  # every paragraph: a key's description may refer to the table's
            first, *rest = doc.split("\n\n")
            out += [f"*{model.__name__}*: " + first.replace("\n", " "), ""]
            out += [p.replace("\n", " ") + "\n" for p in rest]
        out += ["| key | type | default | unit | bounds | description |",
                "|---|---|---|---|---|---|"]
        for path, name, field in keys:
            if not (field.description or _table_doc(field.annotation)):
                log.warning("reference: configuration key %s has no docstring", path)
            out.append("| " + " | ".join([
                f"`{path}`", _cell(_type_text(field.annotation)), _cell(_default_text(field)),
                unit_of(name), _cell(_bounds(field.annotation, field.metadata)),
                _cell(field.description or _table_doc(field.annotation))]) + " |")
        out.append("")
    return "\n".join(out)


def _table_doc(annotation) -> str:
    """A table key without its own docstring: its model's first sentence."""
    children = _children(annotation)
    if not children:
        return ""
    return _model_doc(children[0][1]).split("\n\n")[0]


def _first_use(groups, owners, table) -> bool:
    """True when the model of `table` already had its anchor on an earlier table."""
    model = owners[table]
    for other in groups:
        if other == table:
            return False
        if owners[other] is model:
            return True
    return False


# --- command line ----------------------------------------------------------------------


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def cli_commands() -> dict[str, argparse.ArgumentParser]:
    """The commands of ``orbit-emulator`` (app/cli.py build_parser), by name."""
    from app.cli import build_parser

    return _subcommands(build_parser())


def cli_page() -> str:
    from app.cli import build_parser

    parser = build_parser()
    out = ["# Command line", "",
           "`orbit-emulator COMMAND …` (in the repository: `.venv/bin/orbit-emulator`), "
           "generated from the argument parser of `app/cli.py` when this manual was built. "
           "`orbit-emulator COMMAND --help` prints the same.", "",
           f"*{_cell(parser.description)}*", ""]
    helps = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
    for name, sub in cli_commands().items():
        usage = sub.format_usage().replace("usage: ", "").strip()
        usage = " ".join(usage.split())
        out += [f"## `{name}`", "", _cell(sub.description or helps.get(name) or ""), "",
                "```text", usage, "```", ""]
        arguments = [a for a in sub._actions if not isinstance(a, argparse._HelpAction)]
        out += ["| argument | default | meaning |", "|---|---|---|"] if arguments else [
            "No arguments."]
        for action in arguments:
            names = ", ".join(action.option_strings) or (action.metavar or action.dest)
            if action.choices and not action.option_strings and action.metavar:
                names = str(action.metavar)
            default = "" if action.default in (None, argparse.SUPPRESS, False, []) \
                else f"`{action.default}`"
            meaning = action.help or ""
            if action.choices and action.option_strings:
                meaning += f" (one of: {', '.join(map(str, action.choices))})"
            out.append(f"| `{_cell(str(names))}` | {default} | {_cell(meaning)} |")
        out.append("")
    return "\n".join(out)


# --- REST ------------------------------------------------------------------------------


def openapi_document() -> dict:
    """The app's OpenAPI document (as GET /openapi.json answers it, token required)."""
    from app.backend.server import create_app

    return create_app(token="x" * 32, runs_dir=None).openapi()


PARAMETER_MEANINGS = {  # (the path's first segments, parameter) of those with no description
    ("/api/scenarios", "name"): "a scenario's name (GET /api/scenarios lists them)",
    ("/api/scenarios", "mode"): "`hil` or `ideal` (default: the scenario's own mode)",
    ("/api/telemetry", "format"): "`csv`, the only format",
    ("/api/runs", "run_id"): "a run's id (GET /api/runs lists them)",
    ("/api/runs", "name"): "a file of the run's folder (GET /api/runs/{run_id} lists them)",
}


def _parameter_meaning(path: str, parameter: dict) -> str:
    """The OpenAPI description of a parameter, else PARAMETER_MEANINGS' line for it."""
    if parameter.get("description"):
        return parameter["description"]
    for (prefix, name), meaning in PARAMETER_MEANINGS.items():
        if name == parameter["name"] and path.startswith(prefix):
            return meaning
    log.warning("reference: parameter %r of %s has no description", parameter["name"], path)
    return ""


def rest_page() -> str:
    doc = openapi_document()
    out = ["# REST API", "",
           "Every path of the web app's API, generated from its OpenAPI document when this "
           "manual was built (`serve` answers the same document at `/openapi.json` and "
           "shows it at `/docs`). Behind a token every request carries "
           "`Authorization: Bearer TOKEN`; bodies are JSON, at most 64 KiB.", "",
           _cell(doc.get("info", {}).get("description", "")), ""]
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            out += [f"## `{method.upper()} {path}`", "",
                    _cell(op.get("summary", "")), ""]
            if op.get("description"):
                out += [op["description"].strip(), ""]
            params = op.get("parameters", [])
            if params:
                out += ["| parameter | in | type | meaning |", "|---|---|---|---|"]
                for p in params:
                    schema = p.get("schema", {})
                    kind = schema.get("type") or ", ".join(
                        s.get("type", "") for s in schema.get("anyOf", []))
                    out.append(f"| `{p['name']}` | {p['in']} | {kind} | "
                               f"{_cell(_parameter_meaning(path, p))} |")
                out.append("")
            body = op.get("requestBody", {}).get("content", {}).get("application/json")
            if body:
                out += _body_table(doc, body.get("schema", {}))
            out += ["| status | meaning |", "|---|---|"]
            for status, resp in op.get("responses", {}).items():
                out.append(f"| {status} | {_cell(resp.get('description', ''))} |")
            out.append("")
    return "\n".join(out)


def _schema_type(schema: dict) -> str:
    if "$ref" in schema:
        return schema["$ref"].rsplit("/", 1)[-1]
    if "anyOf" in schema:
        return " or ".join(_schema_type(s) for s in schema["anyOf"])
    if schema.get("type") == "array":
        return f"array of {_schema_type(schema.get('items', {}))}"
    return schema.get("type", "any")


def _body_table(doc: dict, schema: dict) -> list[str]:
    """A request body's fields (its schema's properties), or what it is."""
    name = schema.get("$ref", "").rsplit("/", 1)[-1]
    target = doc.get("components", {}).get("schemas", {}).get(name, schema)
    props = target.get("properties")
    if not props:
        return [f"Body: {_cell(target.get('description') or _schema_type(schema))} (JSON).",
                ""]
    required = set(target.get("required", ()))
    out = [f"Body (JSON, `{name}`): {_cell(target.get('description', ''))}", "",
           "| field | type | required | meaning |", "|---|---|---|---|"]
    for key, prop in props.items():
        out.append(f"| `{key}` | {_cell(_schema_type(prop))} | "
                   f"{'yes' if key in required else ''} | "
                   f"{_cell(prop.get('description', ''))} |")
    return out + [""]


# --- metrics.json ----------------------------------------------------------------------

METRIC_MEANINGS = {
    "scenario": "the scenario's name",
    "mode": "`hil` (arms in the loop) or `ideal` (the reference without arms)",
    "status": "`finished` (ran its duration), `safety_stop` (a protective stop: see "
              "`safety_stop`) or `error` (it raised: see `error`); a web run may also be "
              "`stopped` (by the operator) or `fault` (its loop process died or stalled)",
    "error": "why a run with status `error` or `fault` ended (the exception or the "
             "fault), else null",
    "duration_s": "scenario seconds run",
    "cycles": "loop cycles run",
    "rate_hz": "the loop's rate",
    "realtime_factor": "scenario seconds per wall-clock second (headless)",
    "cycle_time_us": "the loop cycle's computing time, `p50` and `p99`",
    "force_scale": "the factor applied to every measured force before the ODS",
    "torque_scale": "the factor applied to every measured torque before the ODS",
    "scaling": "the dynamic-scaling law and its factors (Explanation: dynamic scaling)",
    "vfdm_iterations": "the VFDM's iterations per cycle",
    "seed": "the seed of the sensor noise",
    "satellites": "one entry per satellite: tracking errors and Δv",
    "robots": "one entry per robot of a hil run: its satellite's tracking errors and its rail",
    "collision": "for a run with contact: impulses, restitution and their interval",
    "safety_stop": "null or `{robot, t_s, reason}`",
    "passivity": "null when off, else the energy the passivity layer removed",
    "collision_forecast": "the pre-flight's forecast of the restitution's spread",
    "capture": "for a capture scenario: whether and how it was captured",
    "success": "the scenario's success criteria, judged",
    "warnings": "what must not be missed, printed as `WARNING: …` under the summary",
    "satellites.id": "1-based satellite number", "satellites.name": "the satellite's name",
    "satellites.position_error_max_m": "max isochronous mockup-vs-ODS position error",
    "satellites.position_error_rms_m": "RMS of the same",
    "satellites.velocity_error_rms_mps": "RMS isochronous velocity error",
    "satellites.attitude_error_max_rad": "max isochronous attitude error",
    "satellites.delta_v_mps": "net change of the ODS velocity over the run",
    "satellites.delta_v_pushed_mps": "sum of the pushes' |Δv|",
    "collision.pair": "the two satellites in contact",
    "collision.impulse_Ns": "the impulse each satellite's ODS received over the contact",
    "collision.impulse_balance": "|J1 + J2| / max(|J1|, |J2|): 0 when action = reaction",
    "collision.normal": "the contact normal (from the true impulse)",
    "collision.off_normal_ratio": "the ODS impulse's part across the normal",
    "collision.true_impulse_Ns": "the impulse the actual mockups exchanged",
    "collision.peak_force_N": "the peak true contact force",
    "collision.contact_duration_s": "how long the mockups touched",
    "collision.touches": "how many separate touches",
    "collision.dt_s": "the loop's time step",
    "collision.contact_energy_J": "energy the contact absorbed",
    "collision.restitution": "coefficient of restitution e of the emulated impact",
    "collision.approach_speed_mps": "the relative speed before the contact",
    "collision.contact_start_s": "when the contact began",
    "collision.contact_end_s": "when it ended",
    "collision.contact_open_at_end": "true when the run ended during the contact",
    "collision.window_s": "the window the impulses are summed over",
    "collision.warnings": "the collision's own warnings",
    "collision.restitution_ideal": "e of the same scenario run in ideal mode, converged",
    "collision.restitution_error": "(e − e_ideal) / e_ideal",
    "collision.true_impulse_ratio": "|J_true| / |J_true,ideal| per satellite",
    "collision.restitution_sd": "the restitution's standard deviation from the noise",
    "collision.restitution_interval_95": "the 95 % interval of e (the noise's, widened by "
    "the larger systematic error, twin's or noisy mean's, on the ideal's side)",
    "collision.restitution_systematic": "the chain's systematic error on this contact, "
    "e_twin − e_ideal (the forecast's noise-free twin)",
    "collision.restitution_bias_noisy": "the chain's systematic error with the noise in, "
    "ē − e_ideal (the forecast's noisy replicates' mean); None within two of its standard "
    "errors of zero",
    "collision.uncertainty": "how the interval was obtained (replicates, method)",
    "collision.rendering_error_m": "Eq. R1: rms of the mockups' overlap against the "
    "satellites' one force lag later, over the contact; null in an ideal run",
    "collision.rendering_error_max_m": "its largest magnitude",
    "collision.contact_depth_m": "the satellites' largest overlap over the contact (the "
    "scale for R1; beyond 5 % of it the run warns)",
    "collision_forecast.restitution_sd": "forecast standard deviation of e",
    "collision_forecast.restitution_sd_se": "the forecast sd's own sampling error (its "
    "replicates)",
    "robots.id": "1-based robot number", "robots.name": "the robot's name",
    "robots.satellite": "the satellite it carries",
    "robots.position_error_max_m": "max isochronous mockup-vs-ODS position error",
    "robots.position_error_rms_m": "RMS of the same",
    "robots.velocity_error_rms_mps": "RMS isochronous velocity error",
    "robots.attitude_error_max_rad": "max isochronous attitude error",
    "robots.rail_travel_m": "the carriage's travel (max - min position); null without a rail",
    "robots.posture_deviation_max_rad": "the arm's largest joint deviation from its posture "
    "while on a rail; null without one",
    "collision_forecast.restitution_mean": "forecast mean of e",
    "collision_forecast.restitution_error_mean": "forecast mean restitution error",
    "collision_forecast.peak_force_N": "the ideal peak force",
    "collision_forecast.noise_force_N": "the sensor's force noise (std)",
    "collision_forecast.peak_to_noise": "peak force over noise",
    "collision_forecast.replicates": "replicates the forecast ran",
    "collision_forecast.replicates_with_restitution": "those that measured an e",
    "collision_forecast.note": "what limits the forecast, in words",
    "collision_forecast.restitution_noise_free": "e of the noise-free twin's contact",
    "collision_forecast.restitution_systematic": "that minus the ideal e: the chain's "
    "systematic error",
    "collision_forecast.velocity_sd_mps": "per satellite, the sd of its velocity after the "
    "contact (R, per axis): the pre-flight's drift check",
    "collision_forecast.rendering_error_m": "the noise-free twin's Eq. R1",
    "collision_forecast.contact_depth_m": "the twin's satellites' contact depth",
    "cycle_time_us.p50": "median cycle time", "cycle_time_us.p99": "99th percentile cycle time",
    "safety_stop.robot": "the arm that stopped", "safety_stop.t_s": "when it stopped",
    "safety_stop.reason": "why (e.g. \"joint 3 speed limit\")",
    "passivity.dissipated_J": "energy removed: `force` over all force ports, `torque` per "
                              "carried satellite",
    "scaling.law": "`paper` or `similarity`",
    "scaling.length": "k_L, orbit metres per lab metre",
    "scaling.time": "k_T, orbit seconds per lab second",
    "scaling.mass": "k_M, orbit kilograms per lab kilogram",
    "scaling.force_scale": "the force scale used", "scaling.torque_scale": "the torque scale",
    "scaling.satellites": "each satellite's virtual and mockup figures",
    "scaling.text": "the law in words",
    "capture.captured": "whether the capture latched", "capture.t_s": "when it latched",
    "capture.position_miss_m": "position miss at the latch",
    "capture.relative_speed_mps": "relative speed at the latch",
    "capture.relative_angle_rad": "relative angle at the latch",
    "capture.relative_rate_radps": "relative angular rate at the latch",
    "capture.peak_contact_force_N": "peak contact force during the capture",
    "capture.residual_rate_radps": "the stack's angular rate after the capture",
    "capture.residual_speed_mps": "the stack's speed after the capture",
    "success.passed": "true when every criterion judged passed",
    "success.libration": "gravity-gradient libration criterion",
    "success.docking": "docking criterion", "success.waypoints": "waypoints criterion",
    "success.final_position": "final-position criterion",
    "success.recovery": "recovery criterion",
    "success.synchronisation": "synchronisation criterion",
}


def metric_fields() -> list[str]:
    """Every documented metrics.json field, as a dotted path (top level, then tables)."""
    from app.campaign.sweep import METRIC_FIELDS

    paths = list(METRIC_FIELDS[""])
    for table, names in METRIC_FIELDS.items():
        if table:
            paths += [f"{table}.{n}" for n in names]
    return paths


def _meaning(table: dict, key: str, what: str) -> str:
    if key not in table:
        log.warning("reference: %s %r has no description in docs_src/reference.py", what, key)
        return ""
    return table[key]


def metrics_page() -> str:
    out = ["# metrics.json", "",
           "Every run (`run`, a sweep's runs, a web run) writes `metrics.json`. Its fields, "
           "generated from `app/campaign/sweep.py` `METRIC_FIELDS` (the list a sweep's "
           "metric paths are checked against) when this manual was built. A figure that is "
           "not finite (e.g. an infinite period) is `null`. Units follow the suffix.", "",
           "| field | unit | meaning |", "|---|---|---|"]
    for path in metric_fields():
        # a field without a unit of its own takes its table's (cycle_time_us.p50: µs)
        unit = unit_of(path) or unit_of(path.rpartition(".")[0])
        out.append(f"| `{path}` | {unit} | "
                   f"{_cell(_meaning(METRIC_MEANINGS, path, 'metrics field'))} |")
    return "\n".join(out) + "\n"


# --- telemetry.csv ---------------------------------------------------------------------

COLUMN_MEANINGS = {
    "t_s": "scenario time",
    "sat.x_m": "ODS position in R", "sat.vx_mps": "ODS velocity in R",
    "sat.qw": "ODS attitude relative to R (unit quaternion, scalar first)",
    "sat.wx_radps": "ODS angular velocity relative to R, body axes",
    "sat.fx_N": "force the ODS received over the step, in R (before the [orbit] scales)",
    "sat.tx_Nm": "torque the ODS received, body axes (before the scales)",
    "rob.x_m": "the actual mockup's COM position in R (the arm's forward kinematics)",
    "rob.qw": "the actual mockup's attitude relative to R",
    "rob.vx_mps": "the actual mockup's velocity in R",
    "rob.q1_rad": "joint angles 1–6",
    "rob.ft_fx_N": "raw F/T force, sensor frame", "rob.ft_tx_Nm": "raw F/T torque",
    "rob.pft_fx_N": "processed wrench on the COM handed to the coupling: force in R",
    "rob.pft_tx_Nm": "processed torque, body axes",
    "sat.true_fx_N": "true external force on the actual mockup, in R",
    "sat.gnc_fx_N": "the satellite's own GNC thrust, in R, orbit units (zeros without GNC)",
    "sat.gnc_tx_Nm": "its reaction wheels' torque, body axes, orbit units",
    "rob.rail_s_m": "the carriage's position s along the rail's axis (0: the base at "
                    "`base_position_m`)",
    "rob.rail_v_mps": "the carriage's speed along the rail's axis",
    "rob.rail_sp_m": "the carriage's position set-point, as the VFDM sent it",
}


def _column_key(kind: str, field: str) -> str:
    """The meaning's key of a column field: x/y/z (and w) share one line."""
    base = re.sub(r"^(q|v|w|f|t|ft_f|ft_t|pft_f|pft_t|true_f|gnc_f|gnc_t)?[wxyz](_)",
                  lambda m: f"{m.group(1) or ''}{'w' if field == 'qw' else 'x'}{m.group(2)}",
                  field)
    if field in ("qw", "qx", "qy", "qz"):
        base = "qw"
    if re.fullmatch(r"q[1-6]_rad", field):
        base = "q1_rad"
    return f"{kind}.{base}"


def telemetry_page() -> str:
    from app.sim.telemetry import GNC_FIELDS, RAIL_FIELDS, ROBOT_FIELDS, SAT_FIELDS, loop_columns

    groups = [("sat", "per satellite `i` (1-based), its ODS state", SAT_FIELDS, "sat{i}_"),
              ("rob", "per arm `k`, its mockup, joints and F/T", ROBOT_FIELDS, "rob{k}_"),
              ("sat", "per satellite `i`, the true force", ("true_fx_N", "true_fy_N",
                                                           "true_fz_N"), "sat{i}_"),
              ("sat", "per satellite `i`, its GNC", GNC_FIELDS, "sat{i}_"),
              ("rob", "per arm `k` on a rail (`[robots.<i>.rail]`), its carriage; only "
                      "those arms, last", RAIL_FIELDS, "rob{k}_")]
    out = ["# telemetry.csv", "",
           "One row per loop cycle (2 ms by default), written by `run` and by every web "
           "run; columns generated from `app/sim/telemetry.py` when this manual was built, "
           "in row order. Units follow the suffix.", "",
           "| column | unit | meaning |", "|---|---|---|",
           f"| `t_s` | s | {COLUMN_MEANINGS['t_s']} |"]
    for kind, title, fields, prefix in groups:
        out.append(f"| *{title}* | | |")
        for f in fields:
            out.append(f"| `{prefix}{f}` | {unit_of(f)} | "
                       f"{_cell(_meaning(COLUMN_MEANINGS, _column_key(kind, f), 'column'))} |")
    cols = loop_columns(2, 2)
    out += ["", f"A two-satellite, two-arm run (the `collision`) has {len(cols)} columns:", "",
            "```text", ", ".join(cols), "```", "",
            "Each arm on a rail adds its three after all of these (`collision-rails`, both "
            f"arms on rails: {len(loop_columns(2, 2, [1, 2]))} columns, ending "
            f"{', '.join(loop_columns(0, 0, [1, 2])[1:])}).", ""]
    return "\n".join(out)


# --- ROS 2 bag -------------------------------------------------------------------------


def bag_topics() -> list[tuple[str, str]]:
    """(topic, message type) of every connection app/runs/bag.py's write_bag opens, read
    from its source: each call ``topic(NAME, TYPE, …)``; an f-string's fields become
    ``<i>``/``<k>``."""
    tree = ast.parse((ROOT / "app/runs/bag.py").read_text())
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "topic" \
                and len(node.args) >= 2:
            name, kind = (_literal(a) for a in node.args[:2])
            if name and kind and (name, kind) not in found:
                found.append((name, kind))
    return found


def _literal(node) -> str:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        parts = []
        for v in node.values:
            if isinstance(v, ast.Constant):
                parts.append(v.value)
            else:
                parts.append("<k>" if "robot" in "".join(parts) else "<i>")
        text = "".join(parts)
        return text.replace("/<i>/", "/sat<i>/") if text.startswith("/<i>/") else text
    return ""


def bag_page() -> str:
    import inspect

    import app.runs.bag as bag

    out = ["# ROS 2 bag", "",
           "`run --bag` (or the web app's download) writes the run as a ROS 2 bag in MCAP "
           "storage with standard messages, stamped with scenario time. The topics and "
           "types below are read from `app/runs/bag.py` when this manual was built.", "",
           "| topic | type | latched |", "|---|---|---|"]
    for name, kind in bag_topics():
        latched = "yes" if name in bag.LATCHED else ""
        out.append(f"| `{name}` | `{kind}` | {latched} |")
    out += ["", "## What each topic holds", "", inspect.getdoc(bag) or "", ""]
    return "\n".join(out)


# --- scenarios -------------------------------------------------------------------------


def scenarios_page() -> str:
    import tomllib

    from app.config import load_config

    out = ["# Scenario library", "",
           "The built-in scenarios, `app/scenarios/*.toml` (`orbit-emulator scenarios` lists "
           "them; `run NAME` runs one). Generated from the files when this manual was "
           "built.", "", "| scenario | extends | satellites | arms | description |",
           "|---|---|---|---|---|"]
    files = sorted((ROOT / "app/scenarios").glob("*.toml"))
    for path in files:
        raw = tomllib.loads(path.read_text())
        cfg = load_config(path)
        out.append(f"| [`{path.stem}`](#{path.stem}) | {raw.get('extends', '')} | "
                   f"{len(cfg.satellites)} | {len(cfg.robots)} | "
                   f"{_cell(cfg.description)} |")
    for path in files:
        out += ["", f"## {path.stem}", "", f"`app/scenarios/{path.name}`:", "",
                "```toml", path.read_text().rstrip(), "```"]
    return "\n".join(out) + "\n"


PAGES = {
    "reference/configuration.md": configuration_page,
    "reference/cli.md": cli_page,
    "reference/rest.md": rest_page,
    "reference/metrics.md": metrics_page,
    "reference/telemetry.md": telemetry_page,
    "reference/bag.md": bag_page,
    "reference/scenarios.md": scenarios_page,
}


SPHINX_ROLE = re.compile(r":(?:func|meth|class|mod|data|attr|obj):(?=<code>)")


def on_page_content(html, page, config, files):
    """MkDocs hook: the docstrings' Sphinx roles (``:func:`name```) read as plain code in
    the Python API page (mkdocstrings renders them as ``:func:<code>name</code>``)."""
    return SPHINX_ROLE.sub("", html)


def on_config(config):
    """MkDocs hook: import ``app`` from this source tree, whatever else is installed (a
    shared venv's editable install may point at another checkout). MkDocs restores
    sys.path after loading a hook module, so this is done here, not at import."""
    if str(ROOT) not in sys.path[:1]:
        sys.path.insert(0, str(ROOT))
    loaded = sys.modules.get("app")
    if loaded is not None and Path(loaded.__file__).resolve().parent != ROOT / "app":
        log.warning("reference: app was imported from %s, not from %s", loaded.__file__, ROOT)
    return config


def on_files(files, config):
    """MkDocs hook: add the generated Reference pages."""
    for uri, make in PAGES.items():
        files.append(File.generated(config, uri, content=make()))
    return files
