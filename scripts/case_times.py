"""Time of a scene's first training-case call (building the full-order model and listing the
cases) against two case runs in the same process, which reuse that model (as a Dask worker
does).

    python3 scripts/case_times.py SCENE [SCENE ...]

SCENE has a ``[reduction.corotational]`` table; needs the ``crokf`` package (``pip install
./python``). Prints one line per scene; wall-clock seconds of one run, not a benchmark.
"""

import sys
import time

import crokf


def main(scenes):
    if not scenes:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    for scene in scenes:
        start = time.perf_counter()
        cases = crokf.training_cases(scene)
        built = time.perf_counter()
        if not cases:
            print(f"{scene}: no training cases; build + list {built - start:.2f} s")
            continue
        crokf.run_training_case(scene, 0)
        first = time.perf_counter()
        crokf.run_training_case(scene, 1 % len(cases))
        second = time.perf_counter()
        print(
            f"{scene}: {len(cases)} cases; build + list {built - start:.2f} s; "
            f"case 0 {first - built:.2f} s; case {1 % len(cases)} {second - first:.2f} s"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
