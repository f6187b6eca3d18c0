"""Parameter points of the study, derived from params.yaml in one place.

The nominal target point, one-at-a-time sweeps (numbers, or words for the categorical CFA pattern) and
cross grids (``target.grids``, e.g. focal length x diameter; docs/workflow.md). Snakemake rules,
DVC stages and the aggregate all take the point list from here, never from a glob of
existing outputs, so stale results are never picked up.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from metraw.errors import MetrawError, read_yaml

NOMINAL = "nominal"


def load_params(path: str | Path = "params.yaml", complete: bool = True) -> dict[str, Any]:
    """Read params.yaml, validated against the workflow's JSON schema (``complete=False``: a file may
    hold only the sections a command reads, e.g. ``training`` for ``metraw train``)."""
    path = Path(path)
    params = read_yaml(path, "parameter file")
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
    checks = list((target.get("sweeps") or {}).items())
    for i, grid in enumerate(target.get("grids") or []):
        checks += [(f"grids/{i}/{k}", v if isinstance(v, list) else [v]) for k, v in grid.items()]
    for parameter, values in checks:
        where = f"target/sweeps/{parameter}" if "/" not in parameter else f"target/{parameter}"
        parameter = parameter.rsplit("/", 1)[-1]
        if parameter not in target["nominal"]:
            raise MetrawError(f"{origin}: {where}: {parameter!r} is not a field of target.nominal "
                              f"(a sweep varies one of: {', '.join(target['nominal'])})")
        for i, value in enumerate(values):
            trial = copy.deepcopy(params)
            trial["target"]["nominal"][parameter] = value
            error = _first_error(trial, schema)
            if error:
                raise MetrawError(f"{origin}: {where}/{i}: {error[1]} (the constraint of target/nominal/{parameter})")
    box = ((params.get("training") or {}).get("pretrain") or {}).get("box") or {}
    for parameter, (low, high) in box.items():
        where = f"training/pretrain/box/{parameter}"
        if parameter not in target["nominal"] or isinstance(target["nominal"][parameter], (str, dict)):
            raise MetrawError(f"{origin}: {where}: {parameter!r} is not a numeric field of target.nominal")
        if not low < high:
            raise MetrawError(f"{origin}: {where}: the range [{low}, {high}] must have low < high")
        for value in (low, high):
            trial = copy.deepcopy(params)
            trial["target"]["nominal"][parameter] = value
            error = _first_error(trial, schema)
            if error:
                raise MetrawError(f"{origin}: {where}: {error[1]} (the constraint of target/nominal/{parameter})")
    if "nominal" in target and (target.get("sweeps") or target.get("grids")):
        try:
            parameter_points(params)
        except MetrawError as exc:
            raise MetrawError(f"{origin}: {exc}") from None


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
    for candidate in (here.parents[3] / "workflow" / "schemas" / "params.schema.yaml",
                      here.parents[1] / "schemas" / "params.schema.yaml"):
        if candidate.is_file():
            return candidate
    raise MetrawError("params schema not found (workflow/schemas/params.schema.yaml)")


#: Sweep parameters whose values are words, not numbers (categorical axes of the study).
CATEGORICAL = frozenset({"cfa_pattern"})
#: Separator of the parts of a grid point's name (``focal_length_m-0.8+diameter_m-0.1``).
GRID_SEPARATOR = "+"


def format_value(value: float | int | str) -> str:
    """Text of a sweep value in point names: ``str`` of the value as YAML loaded it.

    This is exactly how DVC renders ``${item}`` of a params.yaml list in dvc.yaml (its
    ``to_str`` is ``str``), so Snakemake targets and DVC stage outputs name the same paths:
    ``0.8`` -> ``0.8``, ``2.0`` -> ``2.0``, ``2`` -> ``2``, ``100.0e-6`` -> ``0.0001``,
    ``1.0e-5`` -> ``1e-05``, ``mono`` -> ``mono``. Floats are shortest-repr (round-trip exact), so
    two values give the same name only if they are equal. Words (categorical values) must be
    letters, digits and underscores.
    """
    if isinstance(value, str):
        if not value or not all(ch.isalnum() or ch == "_" for ch in value):
            raise MetrawError(f"sweep value {value!r} must be a word of letters, digits and underscores")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MetrawError(f"sweep value {value!r} is not a number or a word")
    return str(int(value)) if isinstance(value, int) else repr(float(value))


def same_value(a: Any, b: Any) -> bool:
    """Whether two values of a target field are the same (numbers by value, words by text)."""
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    return float(a) == float(b)


def point_name(parameter: str, value: float | int | str) -> str:
    """``"<parameter>-<value>"`` (see `format_value`), e.g. ``focal_length_m-0.8``, ``cfa_pattern-mono``."""
    return f"{parameter}-{format_value(value)}"


def grid_point_name(overrides: dict[str, Any]) -> str:
    """A grid point's name: its overrides' `point_name` parts joined by ``+`` in the grid's key order."""
    return GRID_SEPARATOR.join(point_name(k, v) for k, v in overrides.items())


def grid_axes(grid: dict[str, Any]) -> tuple[list[str], dict[str, Any]]:
    """(axis parameters in order, fixed values) of one ``target.grids`` entry: lists are axes."""
    axes = [k for k, v in grid.items() if isinstance(v, list)]
    fixed = {k: v for k, v in grid.items() if not isinstance(v, list)}
    return axes, fixed


def _check_categorical(parameter: str, values: list, nominal: dict[str, Any]) -> None:
    """A CFA sweep compares sensors: a Bayer phase other than the nominal's, or two Bayer phases in one sweep,
    is the same sensor shifted by a pixel, not another design point (the nominal value itself is allowed:
    like any sweep value equal to nominal, it is the nominal point)."""
    from metraw.raw.cfa import cfa_family

    if parameter != "cfa_pattern":
        return
    nominal_cfa = nominal.get("cfa_pattern", "mono")
    bayer = [v for v in values if v != nominal_cfa and cfa_family(v) == "bayer"]
    if bayer and cfa_family(nominal_cfa) == "bayer":
        raise MetrawError(f"cfa_pattern value {bayer[0]!r}: a different Bayer phase than the nominal "
                          f"{nominal_cfa!r} is not a different sensor (sweep mono against a Bayer pattern)")
    if len(set(bayer)) > 1:
        raise MetrawError(f"cfa_pattern values {sorted(set(bayer))}: two Bayer phases are one sensor shifted by a "
                          f"pixel, not two design points (keep one)")


def parameter_points(params: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Ordered mapping point name -> target overrides relative to the nominal point: the listed points
    (`listed_points`), or with ``target.adaptive.enabled`` the adaptive sweep's (`adaptive_points`)."""
    listed = listed_points(params)  # checks the sweeps and grids either way
    return adaptive_points(params) if adaptive_settings(params)["enabled"] else listed


def listed_points(params: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Ordered mapping point name -> target overrides relative to the nominal point (the fixed study).

    ``nominal`` has no overrides; each sweep value gives ``"<parameter>-<value>"`` (e.g. ``diameter_m-0.5``,
    ``cfa_pattern-mono``). A sweep value equal to the nominal value is the nominal point itself and is not
    repeated. Then each ``target.grids`` entry (two or more list-valued axes, other keys fixed) gives the
    cross product of its axes; a grid point whose overrides (values equal to nominal dropped) are those of a
    point already listed *is* that point, the others are named by `grid_point_name` of their overrides.
    """
    nominal = params["target"]["nominal"]
    points: dict[str, dict[str, Any]] = {NOMINAL: {}}
    for parameter, values in (params["target"].get("sweeps") or {}).items():
        if parameter not in nominal:
            raise MetrawError(f"sweep parameter {parameter!r} is not a field of target.nominal")
        for value in values:
            if isinstance(value, str) != (parameter in CATEGORICAL):
                kind = "a word" if parameter in CATEGORICAL else "a number"
                raise MetrawError(f"target.sweeps.{parameter}: value {value!r} must be {kind}")
        _check_categorical(parameter, values, nominal)
        for value in values:
            if same_value(value, nominal[parameter]):
                continue
            points[point_name(parameter, value)] = {parameter: value}
    for overrides in grid_overrides(params):
        key = _override_key(overrides)
        if any(_override_key(o) == key for o in points.values()):
            continue
        points[grid_point_name(overrides)] = overrides
    return points


#: ``target.adaptive`` where params.yaml leaves a key out (issue #70; the rule: metraw.spec.adaptive, the driver:
#: workflow/scripts/adaptive.py, docs/statistics.md "An adaptive sweep"). ``budget``: trained points in all, the
#: initial design included; ``stop_width``: the widest a stretch of a line may be where the GP cannot tell which
#: side of the required IoU the response lies, as a fraction of the line's range (working axis); ``chosen``: the
#: points the driver chose, round by round (lists of overrides), written by the driver, not by hand; ``screen``: the
#: range ends and grid corners are scored by the pretrained box model alone, without training (`screen_points`,
#: metraw.spec.screening), and only the nominal and the categorical values are trained before the rounds;
#: ``screen_offset_sd``: the sd of (fine-tuned - box model) IoU taken until 3 trained points measure it (the 10-point
#: table of docs/training.md: -0.004 to +0.029).
ADAPTIVE_DEFAULTS = {"enabled": False, "budget": 24, "points_per_round": 2, "stop_width": 0.1, "line_candidates": 41,
                     "grid_candidates": 11, "screen": False, "screen_offset_sd": 0.02, "chosen": []}


def adaptive_settings(params: dict[str, Any]) -> dict[str, Any]:
    """``target.adaptive`` with ``ADAPTIVE_DEFAULTS`` filled in."""
    return {**ADAPTIVE_DEFAULTS, **(params["target"].get("adaptive") or {})}


def numeric_ranges(params: dict[str, Any]) -> dict[str, tuple[float, float]]:
    """(low, high) of every numeric swept parameter (`swept_parameters` less the categorical ones) over its sweep
    values, its grid values and the nominal value: the adaptive sweep's lines."""
    target = params["target"]
    values: dict[str, list[float]] = {}
    for name in swept_parameters(params):
        if name in CATEGORICAL:
            continue
        found = [float(v) for v in (target.get("sweeps") or {}).get(name, [])]
        for grid in target.get("grids") or []:
            v = grid.get(name)
            found += [float(x) for x in (v if isinstance(v, list) else [] if v is None else [v])]
        values[name] = found + [float(target["nominal"][name])]
    return {n: (min(v), max(v)) for n, v in values.items()}


def _without_nominal(params: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    nominal = params["target"]["nominal"]
    return {k: v for k, v in overrides.items() if not same_value(v, nominal[k])}


def _name_of(overrides: dict[str, Any]) -> str:
    if not overrides:
        return NOMINAL
    return point_name(*next(iter(overrides.items()))) if len(overrides) == 1 else grid_point_name(overrides)


def _add(points: dict[str, dict[str, Any]], overrides: dict[str, Any]) -> None:
    key = _override_key(overrides)
    if not any(_override_key(o) == key for o in points.values()):
        points[_name_of(overrides)] = overrides


def named_point(params: dict[str, Any], overrides: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """(name, overrides) of the point at ``overrides``: values equal to the nominal dropped, named as
    `parameter_points` names it (``nominal``, `point_name`, or `grid_point_name` in the overrides' order)."""
    overrides = _without_nominal(params, overrides)
    return _name_of(overrides), overrides


def _categorical_points(params: dict[str, Any]) -> dict[str, dict[str, Any]]:
    points: dict[str, dict[str, Any]] = {}
    for name, values in (params["target"].get("sweeps") or {}).items():
        if name in CATEGORICAL:
            for value in values:
                _add(points, _without_nominal(params, {name: value}))
    return points


def _ends(params: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The nominal and both ends of each numeric parameter's range (`numeric_ranges`)."""
    points: dict[str, dict[str, Any]] = {NOMINAL: {}}
    for name, (low, high) in numeric_ranges(params).items():
        for value in (low, high):
            _add(points, _without_nominal(params, {name: value}))
    return points


def _corners(params: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Each grid's corners, its fixed values kept."""
    import itertools

    points: dict[str, dict[str, Any]] = {}
    for grid in params["target"].get("grids") or []:
        axes, fixed = grid_axes(grid)
        for combo in itertools.product(*((min(grid[a]), max(grid[a])) for a in axes)):
            values = {**fixed, **dict(zip(axes, combo))}
            _add(points, _without_nominal(params, {k: values[k] for k in grid}))
    return points


def initial_design(params: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The adaptive sweep's first round of trained points: the nominal, both ends of each numeric parameter's range
    (`numeric_ranges`), every categorical sweep value (measured, never adapted) and each grid's corners; with
    ``target.adaptive.screen`` only the nominal and the categorical values (the ends and corners are scored by the
    box model instead: `screen_points`). A point equal to one already listed is that point (names as
    `parameter_points`)."""
    screen = adaptive_settings(params)["screen"]
    points = {NOMINAL: {}} if screen else _ends(params)
    for overrides in [*_categorical_points(params).values(), *([] if screen else _corners(params).values())]:
        _add(points, overrides)
    return points


def screen_points(params: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The points the pretrained box model alone is scored on, with ``target.adaptive`` enabled and ``screen`` (else
    none): the nominal, each numeric range's ends, each grid's corners, and every trained point at the nominal
    categories (the pairs that measure what fine-tuning adds: metraw.spec.screening)."""
    settings = adaptive_settings(params)
    if not (settings["enabled"] and settings["screen"]):
        return {}
    points = _ends(params)
    for overrides in _corners(params).values():
        _add(points, overrides)
    nominal = params["target"]["nominal"]
    for overrides in adaptive_points(params).values():
        if all(same_value(overrides.get(c, nominal[c]), nominal[c]) for c in CATEGORICAL if c in nominal):
            _add(points, overrides)
    return points


def adaptive_points(params: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The adaptive sweep's points so far: `initial_design`, then each round of ``target.adaptive.chosen`` (every
    chosen value a numeric swept parameter's, inside its range). One line when the budget cannot hold the initial
    design, or the chosen points exceed it."""
    settings = adaptive_settings(params)
    points = initial_design(params)
    if settings["budget"] < len(points):
        raise MetrawError(f"target.adaptive.budget {settings['budget']} is less than the initial design's "
                          f"{len(points)} points (the nominal, each range's ends, categorical values, grid corners)")
    ranges = numeric_ranges(params)
    for r, chosen in enumerate(settings["chosen"], start=1):
        for overrides in chosen:
            for k, v in overrides.items():
                if k not in ranges:
                    raise MetrawError(f"target.adaptive.chosen round {r}: {k!r} is not a numeric swept parameter "
                                      f"({', '.join(ranges)})")
                if isinstance(v, (bool, str)) or not ranges[k][0] <= float(v) <= ranges[k][1]:
                    raise MetrawError(f"target.adaptive.chosen round {r}: {k} = {v!r} lies outside its range "
                                      f"[{ranges[k][0]:g}, {ranges[k][1]:g}]")
            _add(points, _without_nominal(params, overrides))
    if len(points) > settings["budget"]:
        raise MetrawError(f"target.adaptive.chosen: {len(points)} points exceed the budget of {settings['budget']}")
    return points


def point_rounds(params: dict[str, Any]) -> dict[str, int]:
    """Point name -> the adaptive round that added it (0: the initial design)."""
    settings = adaptive_settings(params)
    rounds = {name: 0 for name in initial_design(params)}
    for r, chosen in enumerate(settings["chosen"], start=1):
        for overrides in chosen:
            rounds.setdefault(_name_of(_without_nominal(params, overrides)), r)
    return rounds


def grid_overrides(params: dict[str, Any]) -> list[dict[str, Any]]:
    """Every point of every ``target.grids`` entry as overrides, in the grid's key order (axes vary
    last-fastest), values equal to nominal dropped."""
    import itertools

    nominal = params["target"]["nominal"]
    out = []
    for i, grid in enumerate(params["target"].get("grids") or []):
        axes, fixed = grid_axes(grid)
        if len(axes) < 2:
            raise MetrawError(f"target.grids[{i}] needs at least two list-valued axes, got {axes}")
        for name in grid:
            if name not in nominal:
                raise MetrawError(f"target.grids[{i}]: {name!r} is not a field of target.nominal")
            if name in CATEGORICAL:
                raise MetrawError(f"target.grids[{i}]: {name!r} is categorical; grids span numeric parameters")
        for combo in itertools.product(*(grid[a] for a in axes)):
            values = {**fixed, **dict(zip(axes, combo))}
            overrides = {k: values[k] for k in grid if not same_value(values[k], nominal[k])}
            out.append(overrides)
    return out


def _override_key(overrides: dict[str, Any]) -> frozenset:
    return frozenset((k, v if isinstance(v, str) else float(v)) for k, v in overrides.items())


def pixel_scaled(params: dict[str, Any], values: dict[str, Any]) -> dict[str, Any]:
    """Apply ``target.pixel_scaling`` to a point's full target parameters when its pixel pitch differs
    from the nominal one. ``full_well: area`` (default): full-well capacity scales with the pixel area
    (the same charge per unit area of silicon), ``fixed``: it stays. Read noise, gain and QE stay (a
    stated model: they depend on the readout circuit and the silicon, not the pitch, to first order)."""
    nominal = params["target"]["nominal"]
    scaling = (params["target"].get("pixel_scaling") or {}).get("full_well", "area")
    ratio = float(values["pixel_pitch_m"]) / float(nominal["pixel_pitch_m"])
    if ratio == 1.0 or scaling == "fixed" or values.get("full_well_e") is None:
        return values
    if "full_well_e" in values and not same_value(values["full_well_e"], nominal.get("full_well_e", values["full_well_e"])):
        return values  # the point sets its own full well
    return {**values, "full_well_e": float(values["full_well_e"]) * ratio**2}


def target_at(params: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """The full target parameters of the nominal payload with ``overrides`` (then `pixel_scaled`)."""
    return pixel_scaled(params, {**params["target"]["nominal"], **overrides})


def target_params(params: dict[str, Any], point: str) -> dict[str, Any]:
    """The full target parameter set of a point (nominal updated with its overrides, then `pixel_scaled`)."""
    points = {**screen_points(params), **parameter_points(params)}
    if point not in points:
        raise MetrawError(f"unknown parameter point {point!r}; known: {', '.join(points)}")
    return target_at(params, points[point])


def swept_parameters(params: dict[str, Any]) -> list[str]:
    """Every target field the study varies: the sweeps' parameters, then the grids' (first-seen order)."""
    names = list(params["target"].get("sweeps") or {})
    for grid in params["target"].get("grids") or []:
        names += [k for k in grid if k not in names]
    return names
