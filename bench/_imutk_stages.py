"""Child of ``bench/imutk.py --stages``: the accelerometer calibrate of the IMU-TK Xsens file
(what ``imucald calibrate xsens_acc.mat --columns t,ax,ay,az --nominal-offset 32768
--nominal-scale 4069.76 --json`` does), run once in this fresh process, with the CPU time
of each stage printed as one JSON object (ms): numpy's import, the parser and the first
imports, reading, pose detection, the fit's imports (numpy.random among them), the fit, and
the thermal terms with the JSON.  The tree timed is the one on PYTHONPATH.  The stages run
with the garbage collector on (``imucald.cli.offline.cmd_calibrate`` now pauses it for the
command), so their sum is a little above the command's own time.
Run it with ``OPENBLAS_NUM_THREADS=1``, as the CLI runs (it sets that before numpy's import;
``bench/imutk.py --stages`` does): with a BLAS thread pool the spinning threads' CPU lands in
whichever stage first calls BLAS.
Usage: OPENBLAS_NUM_THREADS=1 python bench/_imutk_stages.py PATH/xsens_acc.mat
"""
import json
import os
import sys
import time

#: the BLAS limited to one thread before numpy's import (run with OPENBLAS_NUM_THREADS=1)
_ONE_BLAS_THREAD = (os.environ.get("OPENBLAS_NUM_THREADS") == "1"
                    and os.environ.get("MKL_NUM_THREADS", "1") == "1")

_C = time.process_time
_T = [_C()]


def _mark():
    _T.append(_C())


def main(path: str) -> dict:
    import numpy  # noqa: F401
    _mark()
    from imucald.cli.checks import check_args
    from imucald.cli.parser import build_parser
    args = build_parser("calibrate").parse_args(
        ["calibrate", path, "--columns", "t,ax,ay,az", "--nominal-offset", "32768",
         "--nominal-scale", "4069.76", "--json"])
    check_args(args)
    if _ONE_BLAS_THREAD:            # as cli/__init__.py says when it set it before numpy
        try:
            from imucald.numerics import blas
            blas.ONE_THREAD = True
        except ImportError:         # an older tree (--before): no such switch
            pass
    from imucald.numerics import allocator as _malloc
    _malloc.tune()
    from imucald.fitting.inputs import load_input
    from imucald.fitting.stillness.poses import poses_and_pieces
    from imucald.cli import offline
    _mark()
    _, rec = load_input(path, args.columns.split(","), args.nominal_scale, args.nominal_offset, None)
    _mark()
    poses, pieces = poses_and_pieces(rec, window_s=args.window_s, k=args.threshold_k,
                                     min_still_s=args.min_still_s)
    _mark()
    import numpy.random  # noqa: F401
    from imucald.fitting.fit import fit_norm  # noqa: F401
    from imucald.fitting.noise.colour import pose_colour_inflation  # noqa: F401
    from imucald.cli.thermal import fit_thermal
    _mark()
    cal, chip, infl = offline._fit_accel(args, rec, poses, pieces, poses.detector, "triangular9", None)
    _mark()
    tf = fit_thermal("accel", pieces, cal, chip, infl, args.thermal_min_span, args.seed)
    # the file's part is made only for -o (or the gyro, or plots): not here, as in the command
    json.dumps(offline._calibrate_json("accel", cal, poses.detector, rec, None, None, None, tf))
    _mark()
    names = ["numpy import", "parser + first imports", "reading", "pose detection",
             "fit imports", "fit", "thermal + JSON"]
    return {n: (_T[i + 1] - _T[i]) * 1e3 for i, n in enumerate(names)}


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1])))
