"""``metraw aggregate``: per-point results -> GP response surfaces, tolerances, spec.yaml, figures. The command
parses its arguments and calls `metraw.spec.aggregate` (what it reads and writes is described there)."""

from __future__ import annotations

import dataclasses

from metraw.spec.aggregate import DEFAULT_COMPRESSION, DEFAULT_METRICS, DEFAULT_SCREEN, AggregateOptions


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
    p.add_argument("--screen-pattern", default=DEFAULT_SCREEN,
                   help="path of a point's box-model score ({results}, {point}; an adaptive sweep with "
                   "target.adaptive.screen: rule screen)")
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
