"""How much of the default call the frame's noise measurement costs: same-run medians, calls alternating.

    python benchmarks/noise_share.py FOLDER [FOLDER ...] [--repeats 25]

Each FOLDER is a frame in the sensor sample's layout (``depth.npy`` in metres, ``K.json``). Per frame, three calls
alternate: the default (`surfnorm.estimate(depth, K)`, every core), the same with the noise profile measured
beforehand and handed to it (the measurement left out of the timed call, the normals the same), and OpenCV's
LINEMOD (window 5, one thread, as in the sensor benchmark). It prints their medians and the ratios to LINEMOD:
what the default would take if its noise measurement were free. A diagnostic, not a mode of surfnorm.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    from surfnorm.bench.peers import single_thread

    single_thread()  # LINEMOD on one thread; surfnorm's own calls use every core
    import surfnorm
    import surfnorm.kernels.adaptive_fit as fit
    from surfnorm.bench.sensor import alternating_medians, linemod_entry, read_sensor_frame
    from surfnorm.kernels.sensor_noise import noise_profile

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--repeats", type=int, default=25)
    args = ap.parse_args(argv)
    linemod = linemod_entry("noise_share")
    if linemod is None:
        return 2
    measure = fit.noise_profile
    print("| frame | default, ms | noise given, ms | LINEMOD, ms | default / LINEMOD | noise given / LINEMOD |")
    print("|---|---|---|---|---|---|")
    for folder in args.folders:
        fr = read_sensor_frame(Path(folder))
        z = np.ascontiguousarray(fr.depth, np.float32)
        valid = z > 0
        profile = noise_profile(z, valid, math.sqrt(fr.K.fx * fr.K.fy))

        def given(z=z, K=fr.K, profile=profile):
            fit.noise_profile = lambda *a, **k: profile
            try:
                return surfnorm.estimate(z, K)
            finally:
                fit.noise_profile = measure

        calls = {
            "default": lambda z=z, K=fr.K: surfnorm.estimate(z, K),
            "given": given,
            "linemod": lambda z=z, K=fr.K, valid=valid: linemod.call(z, K, valid),
        }
        assert np.array_equal(calls["default"](), calls["given"](), equal_nan=True)
        ms = alternating_medians(calls, args.repeats, warm_up=1)
        print(
            f"| {fr.name} | {ms['default']:.2f} | {ms['given']:.2f} | {ms['linemod']:.2f} "
            f"| {ms['default'] / ms['linemod']:.2f} | {ms['given'] / ms['linemod']:.2f} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
