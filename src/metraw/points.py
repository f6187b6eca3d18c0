"""Parameter points of the study, derived from params.yaml in one place.

The nominal target point plus one-at-a-time sweeps (DESIGN.md section 6). Snakemake rules,
DVC stages and the aggregate all take the point list from here, never from a glob of
existing outputs, so stale results are never picked up.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from metraw.errors import MetrawError

NOMINAL = "nominal"


def load_params(path: str | Path = "params.yaml", complete: bool = True) -> dict[str, Any]:
    """Read params.yaml, validated against the workflow's JSON schema (``complete=False``: a file may
    hold only the sections a command reads, e.g. ``training`` for ``metraw train``)."""
    path = Path(path)
    try:
        params = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise MetrawError(f"parameter file {path} not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MetrawError(f"cannot read parameter file {path}: {getattr(exc, 'strerror', None) or exc}") from None
    except yaml.YAMLError as exc:
        raise MetrawError(f"parameter file {path} is not valid YAML: {' '.join(str(exc).split())}") from None
    if not isinstance(params, dict):
        raise MetrawError(f"parameter file {path} must hold a mapping")
    validate_params(params, path, complete)
    return params


def validate_params(params: dict[str, Any], origin: str | Path = "params", complete: bool = True) -> None:
    """Validate against workflow/schemas/params.schema.yaml (shipped with the package too); with
    ``complete=False`` the top-level sections are optional (those present are validated in full).

    Each sweep value must name a field of ``target.nominal`` and meet that field's constraint: it is
    checked by validating the parameters with the value in place of the nominal one (a focal-length
    sweep value of 0 is refused like a nominal focal length of 0)."""
    import copy

    schema = yaml.safe_load(_schema_path().read_text())
    if not complete:
        schema["required"] = []
    error = _first_error(params, schema)
    if error:
        raise MetrawError(f"{origin}: {error[0]}: {error[1]}")
    target = params.get("target") or {"nominal": {}}
    for parameter, values in (target.get("sweeps") or {}).items():
        where = f"target/sweeps/{parameter}"
        if parameter not in target["nominal"]:
            raise MetrawError(f"{origin}: {where}: {parameter!r} is not a field of target.nominal "
                              f"(a sweep varies one of: {', '.join(target['nominal'])})")
        for i, value in enumerate(values):
            trial = copy.deepcopy(params)
            trial["target"]["nominal"][parameter] = value
            error = _first_error(trial, schema)
            if error:
                raise MetrawError(f"{origin}: {where}/{i}: {error[1]} (the constraint of target/nominal/{parameter})")


def _first_error(params: dict[str, Any], schema: dict[str, Any]) -> tuple[str, str] | None:
    """(path, message) of the best schema violation of ``params``, or None."""
    import jsonschema

    error = jsonschema.exceptions.best_match(jsonschema.validators.validator_for(schema)(schema).iter_errors(params))
    if error is None:
        return None
    return "/".join(str(p) for p in error.absolute_path) or "(top level)", error.message


def write_effective_params(params: dict[str, Any], path: str | Path) -> Path:
    """Write ``params`` as YAML to ``path`` (atomically, and only when the content differs) and return it.

    The workflow's configuration is params.yaml merged with Snakemake's ``--config`` overrides; the
    rules hand this file to ``metraw ... --params`` so each command sees what the DAG was built from."""
    from metraw.atomic import atomic_path

    path = Path(path)
    text = yaml.safe_dump(params, sort_keys=False)
    if not path.is_file() or path.read_text() != text:
        with atomic_path(path, overwrite=True) as tmp:
            tmp.write_text(text)
    return path


def _schema_path() -> Path:
    here = Path(__file__).resolve()
    for candidate in (here.parents[2] / "workflow" / "schemas" / "params.schema.yaml",
                      here.parent / "schemas" / "params.schema.yaml"):
        if candidate.is_file():
            return candidate
    raise MetrawError("params schema not found (workflow/schemas/params.schema.yaml)")


def format_value(value: float | int) -> str:
    """Text of a sweep value in point names: ``str`` of the value as YAML loaded it.

    This is exactly how DVC renders ``${item}`` of a params.yaml list in dvc.yaml (its
    ``to_str`` is ``str``), so Snakemake targets and DVC stage outputs name the same paths:
    ``0.8`` -> ``0.8``, ``2.0`` -> ``2.0``, ``2`` -> ``2``, ``100.0e-6`` -> ``0.0001``,
    ``1.0e-5`` -> ``1e-05``. Floats are shortest-repr (round-trip exact), so two values
    give the same name only if they are equal.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MetrawError(f"sweep value {value!r} is not a number")
    return str(int(value)) if isinstance(value, int) else repr(float(value))


def point_name(parameter: str, value: float | int) -> str:
    """``"<parameter>-<value>"`` (see `format_value`), e.g. ``focal_length_m-0.8``."""
    return f"{parameter}-{format_value(value)}"


def parameter_points(params: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Ordered mapping point name -> target overrides relative to the nominal point.

    ``nominal`` has no overrides; each sweep value gives ``"<parameter>-<value>"`` (e.g. ``diameter_m-0.5``). A sweep
    value equal to the nominal value is the nominal point itself and is not repeated.
    """
    nominal = params["target"]["nominal"]
    points: dict[str, dict[str, Any]] = {NOMINAL: {}}
    for parameter, values in (params["target"].get("sweeps") or {}).items():
        if parameter not in nominal:
            raise MetrawError(f"sweep parameter {parameter!r} is not a field of target.nominal")
        for value in values:
            if float(value) == float(nominal[parameter]):
                continue
            points[point_name(parameter, value)] = {parameter: value}
    return points


def target_params(params: dict[str, Any], point: str) -> dict[str, Any]:
    """The full target parameter set of a point (nominal updated with its overrides)."""
    points = parameter_points(params)
    if point not in points:
        raise MetrawError(f"unknown parameter point {point!r}; known: {', '.join(points)}")
    return {**params["target"]["nominal"], **points[point]}
