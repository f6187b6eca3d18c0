"""``metraw aggregate``: per-point results -> GP response surfaces, tolerances, spec.yaml, figures.

The point list comes from params.yaml (`metraw.study.points.parameter_points`), never from a glob;
every point's metrics (and compression) file must exist. Outputs under ``--out``:
``spec.yaml``, ``aggregate.json``, ``figures/*.png`` and ``plots/*.csv`` (for ``dvc plots``).
With replicate models a point's IoU, precision, recall and object F1 (synthetic and real) are the means over
the replicates (``iou_measurement``, ``with_replicate_means``); box scores are the first model's.

Sim-to-real (``--real-metrics-pattern``, issue #16): each point's synthetic-trained model scored on the
real images emulated through the same point. aggregate.json then holds per point ``real_iou`` (+ sd),
``real_precision``, ``real_recall``, ``real_box_iou`` (box labels: predicted objects as boxes),
``real_labels``, ``sim_to_real_gap`` (synthetic test IoU - real IoU, with its sd) and ``sim_to_real_note``, plus a top-level ``sim_to_real`` summary (nominal gap, whether it
is within ``--gap-tolerance``; ``--source-real-metrics``: the drone-resolution reference); the IoU
figures draw the real points beside the synthetic ones. The GP, tolerances and spec.yaml are fitted
to the synthetic test IoU only: the real images are a check of transfer, not the basis of the spec.
"""

from __future__ import annotations

import dataclasses

from metraw.spec.aggregate import DEFAULT_COMPRESSION, DEFAULT_METRICS, AggregateOptions


def register(sub) -> None:
    p = sub.add_parser("aggregate", help="fit GPs over the parameter points; write spec.yaml, figures, tables",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--params", default="params.yaml", help="parameter file (point list, spec.required_iou)")
    p.add_argument("--results", default="results", help="folder of per-point results")
    p.add_argument("--out", default="results", help="output folder (spec.yaml, aggregate.json, figures/, plots/)")
    p.add_argument("--metrics-pattern", default=DEFAULT_METRICS,
                   help="path of a point's segmenter metrics; {results} and {point} are filled in")
    p.add_argument("--compression-pattern", default=DEFAULT_COMPRESSION,
                   help="path of a point's compression.json ({results}, {point}); '' to leave compression out")
    p.add_argument("--stores-pattern", default="",
                   help="path of a point's emulated store (e.g. 'data/targets/{point}.zarr') for Fig. 6 examples")
    p.add_argument("--real-metrics-pattern", default="",
                   help="path of a point's metrics on its emulated real images ({results}, {point}), e.g. "
                   "'results/points/{point}/real_metrics.json'; '' (default): no sim-to-real columns")
    p.add_argument("--source-real-metrics", default="",
                   help="metrics of the drone-resolution (source) model on the real images (sim-to-real reference)")
    p.add_argument("--source-metrics", default="",
                   help="metrics of the source model on its synthetic test split (for the reference's gap)")
    p.add_argument("--gap-tolerance", type=float, default=None,
                   help="largest |synthetic - real IoU| counted as transferring (default 0.05)")
    p.add_argument("--example-index", type=int, default=0, help="image index shown in Fig. 6")
    p.add_argument("--extrapolate", type=float, default=0.0,
                   help="extend tolerance search beyond the sampled range by this fraction of it (flagged)")
    p.add_argument("--seed", type=int, default=0, help="seed of the GP optimiser restarts")
    p.set_defaults(func=run)


def run(args) -> int:
    from metraw.spec.aggregate import aggregate

    return aggregate(AggregateOptions(**{f.name: getattr(args, f.name) for f in dataclasses.fields(AggregateOptions)}))
