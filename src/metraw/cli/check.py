"""``metraw check``: PASS / NORMALISE / REJECT an image against a specification (results/spec.yaml).

Reads the image (a raw file via `metraw.io.read_raw`, or one image of a metraw store:
``STORE.zarr#INDEX`` or ``STORE.zarr --index INDEX``; ``--profile P.json`` replaces its profile),
compares its profile geometry (GSD, diffraction and smear on the ground) and the signal level
measured from its pixels with the spec, checks the profile's noise model against the pixels
(single-frame fit), and prints the verdict with its reasons and, for NORMALISE, the chain of raw
functions that brings the image to spec (see `metraw.spec`). The verdict is a result, not an error:
the exit status is 0 whatever it is, or with ``--exit-code`` 1 for REJECT (for scripts that gate on it, as
``git diff --exit-code``); 2 stays an error of the input.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from metraw.atomic import atomic_path
from metraw.errors import MetrawError
from metraw.io.store import RawStore
from metraw.raw.image import RawImage


def add_input_arguments(p) -> None:
    p.add_argument("image", help="raw image file, or an image of a metraw store: STORE.zarr#INDEX or STORE.zarr --index I")
    p.add_argument("--index", type=int, default=None, help="image index in a store")
    p.add_argument("--spec", default="results/spec.yaml", help="specification (default results/spec.yaml)")
    p.add_argument("--profile", default=None,
                   help="calibration profile JSON replacing the image's own (a full profile with schema_version, "
                        "or an object of fields to change, e.g. {\"gain_dn_per_e\": 0.5})")


def split_image_argument(text: str, index: int | None) -> tuple[Path, int | None]:
    """(path, index) from ``STORE.zarr#I`` or a path plus ``--index``; a file name containing '#'
    is taken as it is when it exists."""
    path = Path(text)
    if "#" in text and not path.exists():
        head, _, tail = text.rpartition("#")
        try:
            i = int(tail)
        except ValueError:
            raise MetrawError(f"{text}: the part after '#' must be an image index (STORE.zarr#3)") from None
        if index is not None and index != i:
            raise MetrawError(f"{text} and --index {index} name different images")
        if not RawStore.is_store(Path(head)):
            raise MetrawError(f"{head} is not a metraw store (no zarr.json): '#INDEX' applies to stores only")
        return Path(head), i
    return path, index


def load_image(args) -> RawImage:
    """The image named on the command line (store + index, or a file), with ``--profile`` applied."""
    path, index = split_image_argument(args.image, args.index)
    if RawStore.is_store(path):
        if index is None:
            raise MetrawError(f"{path} is a store: choose an image with STORE.zarr#INDEX or --index")
        store = RawStore.open(path)
        if not -len(store) <= index < len(store):
            raise MetrawError(f"image index {index} out of range for {path} ({len(store)} images)")
        image = store[index]
    else:
        if index is not None:
            raise MetrawError(f"{path} is not a metraw store: an image index applies to stores only")
        from metraw.io import read_raw

        image = read_raw(path)
    if args.profile:
        from metraw.raw.profile import load_profile

        profile = load_profile(args.profile, base=image.profile)
        image = RawImage(image.data, profile, image.mask, image.flags, image.provenance, image.meta)
    return image


def register(sub) -> None:
    p = sub.add_parser("check", help="PASS / NORMALISE / REJECT an image against results/spec.yaml",
                       description=__doc__.split("\n\n")[0])
    add_input_arguments(p)
    p.add_argument("--json", default=None, help="also write the full decision as JSON here")
    p.add_argument("--no-noise", action="store_true", help="skip the single-frame noise check")
    p.add_argument("--exit-code", action="store_true",
                   help="exit with status 1 when the verdict is REJECT (0: PASS or NORMALISE; 2: an input error)")
    p.set_defaults(func=run)


def format_decision(decision) -> str:
    lines = [decision.verdict]
    lines += [f"  reason: {r}" for r in decision.reasons]
    for name, f in decision.properties.items():
        v = "unknown" if f["value"] is None else f"{f['value']:.4g}"
        if name == "predicted_iou":  # the spec's property model (metraw.spec.property_model)
            lines.append(f"  predicted IoU: {v} +- {f['sd']:.3f} (required {f['required']:g})")
        elif "sampled_min" in f:
            lines.append(f"  {name}: {v} {f['unit']} ({f['source']}), sampled [{f['sampled_min']:.4g}, "
                         f"{f['sampled_max']:.4g}]: {f['status']}")
        else:
            lines.append(f"  {name}: {v} {f['unit']} ({f['source']}), spec [{f['min']:.4g}, {f['max']:.4g}], "
                         f"optimal {f['optimal']:.4g}: {f['status']}")
    if decision.noise and decision.noise.get("measured"):
        for name, c in decision.noise["checks"].items():
            claimed = (f"{c['claimed']:.4g} +- {c['claimed_u']:.2g}" if math.isfinite(c["claimed_u"])
                       else f"{c['claimed']:.4g} (marked unknown in the profile)")
            lines.append(f"  noise {name}: measured {c['measured']:.4g} +- {c['measured_u']:.2g}, claimed "
                         f"{claimed}{' CONTRADICTS' if c['contradicts'] else ''}")
    for i, step in enumerate(decision.chain, 1):
        lines.append(f"  step {i}: {step['function']}({', '.join(f'{k}={v:.4g}' if isinstance(v, float) else f'{k}={v}' for k, v in step['params'].items())})"
                     f"  # {step['effect']}")
    return "\n".join(lines)


def run(args) -> int:
    from metraw.spec.builder import Specification
    from metraw.spec.check import check

    spec = Specification.load(args.spec)
    image = load_image(args)
    decision = check(image, spec, measure_noise=not args.no_noise)
    print(format_decision(decision))
    if args.json:
        with atomic_path(args.json, overwrite=True) as tmp:
            tmp.write_text(json.dumps({"image": str(args.image), "index": args.index, **decision.to_dict()},
                                      indent=1, default=float) + "\n")
    return 1 if args.exit_code and decision.verdict == "REJECT" else 0
