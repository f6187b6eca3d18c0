"""``metraw verify INPUT [--step Q] [--profile P.json | --black B --cfa PATTERN]``: encode, decode, self-check."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("verify", help="encode and decode a raw image and print the codec self-check")
    p.add_argument("input")
    p.add_argument("--step", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--profile")
    p.add_argument("--black", type=float)
    p.add_argument("--cfa")
    p.set_defaults(func=run)


def run(args) -> int:
    from metraw import codec
    from metraw.cli.encode import load_or_calibrate
    from metraw.codec.selfcheck import format_check, self_check

    image, _ = load_or_calibrate(args.input, args.profile, args.black, args.cfa)
    blob = codec.encode(image, step=args.step, seed=args.seed)
    decoded = codec.decode(blob)
    stats = self_check(image, decoded, args.step)
    stats["bits_per_pixel"] = 8 * len(blob) / image.data.size
    print(format_check(stats))
    return 0 if stats["bound_violations"] == 0 else 1
