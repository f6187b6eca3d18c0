import re

# Shared definitions: the parameter points come from params.yaml via metraw.points,
# never from a glob of existing outputs.

from metraw.points import parameter_points, target_params

POINTS = list(parameter_points(config))
SOURCE_STORE = "data/source.zarr"


def point_target(wildcards):
    """Full target parameters of a point (tracked by Snakemake as a rule param)."""
    return target_params(config, wildcards.point)


wildcard_constraints:
    point="|".join(re.escape(p) for p in POINTS),
