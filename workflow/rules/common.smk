import re

# Shared definitions: the parameter points come from params.yaml via metraw.study.points,
# never from a glob of existing outputs.

from snakemake.exceptions import WorkflowError

from metraw.study.points import parameter_points, target_params
from metraw.provenance import code_digest
from metraw.study.sources import calibration_method
from metraw.segment.pretrain import (draws_extra_scenes, fine_tuned_points, point_patterns, pretrain_settings,
                                     pretrained_patterns)

POINTS = list(parameter_points(config))
SOURCE_CAMERA = "results/source/camera.json"  # the raws source's calibrated camera (rule source_camera)
METRAW_CODE = code_digest()  # the aggregate's cache key covers metraw's code (workflow/rules/aggregate.smk)
SOURCE_STORE = "data/source.zarr"
# The stores many jobs read (the source: every emulation, training and the pretraining; the real photos: every
# point's emulate_real) are read from a decoded working copy, the raw array uncompressed (rule decode_store: ~12
# instead of ~42 ms of CPU per 1 MP image, at 4x the disk). A reader lists both: the store, whose change reruns it,
# and the copy, what its command reads, as ancient (a copy a DVC stage wrote after the readers' outputs reruns
# none of them). The copy is an ordinary intermediate output: deleting it reruns its readers, as deleting a store
# would. (Not temp(): Snakemake would re-create a deleted temporary copy for one new point and then rerun every
# reader, since ancient spares only readers of an existing file.)
SOURCE_DECODED = "data/source.decoded.zarr"

# Pretraining across the box (params.yaml training.pretrain; workflow/rules/segment.smk): one pretraining per CFA
# pattern among the points (one network per replicate each); every point fine-tunes its pattern's.
PRETRAIN = pretrain_settings(config)
PRETRAINED_MODEL = "results/pretrained/{cfa_pattern}/model"
PRETRAINED_PATTERNS = pretrained_patterns(config)
PRETRAIN_SCENES = "data/pretrain_scenes.zarr"
PRETRAIN_EXTRA = [PRETRAIN_SCENES] if draws_extra_scenes(config) else []
PRETRAINED_POINTS = set(fine_tuned_points(config))
POINT_PATTERNS = point_patterns(config)

# Sim-to-real benchmark (workflow/rules/sim_to_real.smk, when SIM_TO_REAL): the real photos as a store, emulated
# per point, scored by each point's model; the drone-resolution model scored on the un-emulated store.
REAL_STORE = "data/real.zarr"
REAL_DECODED = "data/real.decoded.zarr"
REAL_POINT_METRICS = "results/points/{point}/real_metrics.json"
SOURCE_REAL_METRICS = "results/source/real_metrics.json"
SIM_TO_REAL_METRICS = (expand(REAL_POINT_METRICS, point=POINTS) + [SOURCE_REAL_METRICS]) if SIM_TO_REAL else []


def point_target(wildcards):
    """Full target parameters of a point (tracked by Snakemake as a rule param)."""
    return target_params(config, wildcards.point)


wildcard_constraints:
    point="|".join(re.escape(p) for p in POINTS),


def _check_dvc_points(check):
    """Fail in one line when a DVC stage stands for points that params.yaml does not give."""
    known = set(POINTS)
    if "dvc_point" in check and check["dvc_point"] not in known:
        raise WorkflowError(
            f"DVC stage for point {check['dvc_point']!r}, which params.yaml does not give (a sweep value equal to "
            f"the nominal one is the nominal point); points: {', '.join(POINTS)}")
    if "dvc_points" in check:
        listed = check["dvc_points"].split(",")
        if sorted(listed) != sorted(known):
            raise WorkflowError(
                f"dvc.yaml's aggregate stage lists points {', '.join(listed)} but params.yaml gives "
                f"{', '.join(POINTS)}: regenerate it with `python workflow/scripts/dvc_yaml.py`")


_check_dvc_points(DVC_CHECK)
