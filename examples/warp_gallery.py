"""Draw every warp of jaxrt.sampling.warp.REGISTRY (points, histogram, integrated pdf) into one PNG.

Usage: python examples/warp_gallery.py [-o warps.png] [-n NUM_SAMPLES]
"""

import argparse

from jaxrt.validation.gallery import make_gallery


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("-o", "--output", default="warps.png")
    parser.add_argument("-n", "--num-samples", type=int, default=100_000)
    args = parser.parse_args(argv)
    results = make_gallery(args.output, num_samples=args.num_samples)
    print(f"wrote {args.output}: {sum(r.passed for r in results)}/{len(results)} warps pass χ²")


if __name__ == "__main__":
    main()
