"""``metraw normalise``: apply the chain that brings a better-than-spec image to spec.

Runs `metraw.spec.check.check`; a NORMALISE verdict's chain (binning to a coarser GSD, photon
redistribution through a blur kernel, binomial thinning of light) is applied with
`metraw.physics.rawfunc` and the result written atomically with its new profile and provenance: a metraw
raw TIFF when OUT ends in .tif/.tiff (`metraw.io.tiff.write_tiff`), else a one-image metraw store.
PASS writes the image unchanged; REJECT writes nothing and exits with an error (status 2).
"""

from __future__ import annotations

from pathlib import Path

from metraw.errors import MetrawError


def register(sub) -> None:
    from metraw.cli.check import add_input_arguments

    p = sub.add_parser("normalise", help="degrade a better-than-spec image to spec (raw functions only)",
                       description=__doc__.split("\n\n")[0])
    add_input_arguments(p)
    p.add_argument("out", help="output: a metraw raw TIFF (.tif/.tiff) or a one-image store (e.g. OUT.zarr)")
    p.add_argument("--seed", type=int, default=0, help="seed of the raw functions' random draws")
    p.add_argument("--no-noise", action="store_true", help="skip the single-frame noise check")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.set_defaults(func=run)


def run(args) -> int:
    from metraw.cli.check import format_decision, load_image
    from metraw.io.store import RawStore
    from metraw.spec.builder import Specification
    from metraw.spec.check import apply_chain, check

    spec = Specification.load(args.spec)
    image = load_image(args)
    decision = check(image, spec, measure_noise=not args.no_noise)
    print(format_decision(decision))
    if decision.verdict == "REJECT":
        raise MetrawError("image rejected, nothing written: " + "; ".join(decision.reasons))
    out = apply_chain(image, decision.chain, seed=args.seed)
    if Path(args.out).suffix.lower() in (".tif", ".tiff"):
        from metraw.io.tiff import write_tiff

        write_tiff(args.out, out, overwrite=args.overwrite)
    else:
        with RawStore.create(args.out, overwrite=args.overwrite) as store:
            store.append(out)
    print(f"wrote {args.out}: {out.shape[0]} x {out.shape[1]} px, GSD "
          f"{out.profile.gsd_m if out.profile.gsd_m is None else round(out.profile.gsd_m, 4)} m, "
          f"steps: {', '.join(s['function'] for s in decision.chain) or 'none'}")
    return 0
