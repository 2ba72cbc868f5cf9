"""Arguments checked before anything is opened: number ranges (argparse types), output
paths (a file that can be created, not a directory), rates the chosen board can run at.

numpy-free: the parser uses the types, :func:`check_args` runs before every command.
"""
from __future__ import annotations

import argparse
import math
import os

from ..errors import CannotCreate, UserError

__all__ = ["positive_float", "non_negative_float", "per_sensor", "finite_float", "fraction", "seed",
           "bus_number", "at_least", "check_args", "output_file", "output_dir", "LIMITS", "number_in",
           "count_in", "SIM_MAX_SAMPLES"]

#: The stated limits of the arguments that imply memory or time (docs/changes/issue-21.md):
#: a value beyond is refused in one line before anything runs.  (low, high, unit)
LIMITS = {
    "rate": (0.0, 10000.0, "Hz"),         # beyond every supported chip's output rate (8 kHz)
    "seconds": (0.0, 1e7, "s"),           # record: 116 days (written as it comes: no memory)
    "hold": (0.0, 3600.0, "s"),
    "move": (0.0, 3600.0, "s"),
    "speed": (0.0, 1000.0, "x"),          # the emulator at 1 kHz x 1000 is 1 M samples/s of CPU
    "duration": (0.0, 1e9, "s"),
    "tremor": (0.0, 100.0, "deg/s"),      # a hand's is 0.5-2
    "sway": (0.0, 10.0, "deg"),           # a hand's is 0.05-0.4 (RMS per axis)
    "window": (0.0, 3600.0, "s"),
    "temp_rise": (-150.0, 150.0, "degC"),
}
#: simulate: the most samples one simulation may hold (~450 bytes each in memory at its
#: peak: 1 M samples ~ 450 MB, ~15 s on a Pi 4 core)
SIM_MAX_SAMPLES = 1_000_000


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    v = _number(text)
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"{text} is not a number > 0")
    return v


def per_sensor(text: str) -> "float | dict[str, float]":
    """argparse type of --nominal-scale / --nominal-offset: one finite number for every sensor
    column, or one per sensor as ``accel=16384,gyro=131`` (accel, gyro, mag; and temp, a
    temperature column in counts, which one number leaves as it is), a dict."""
    if "=" not in text:
        try:
            return finite_float(text)
        except argparse.ArgumentTypeError as e:
            raise argparse.ArgumentTypeError(f"{e} (one for every sensor, or accel=N,gyro=N,mag=N)") from None
    out = {}
    for part in text.split(","):
        key, _, val = part.partition("=")
        key = key.strip()
        if key not in ("accel", "gyro", "mag", "temp") or key in out:
            raise argparse.ArgumentTypeError(
                f"{part!r} in {text!r}: expected accel=N, gyro=N, mag=N and temp=N, each at most once")
        try:
            out[key] = finite_float(val)
        except argparse.ArgumentTypeError as e:
            raise argparse.ArgumentTypeError(f"{part!r} in {text!r}: {e}") from None
    return out


def finite_float(text: str) -> float:
    """argparse type: a finite number (no nan, no inf)."""
    v = _number(text)
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text} is not a finite number")
    return v


def fraction(text: str) -> float:
    """argparse type: a number strictly between 0 and 1 (a confidence level)."""
    v = finite_float(text)
    if not 0 < v < 1:
        raise argparse.ArgumentTypeError(f"{text} is not a fraction between 0 and 1, e.g. 0.95")
    return v


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def seed(text: str) -> int:
    """argparse type: a random seed, an integer >= 0 (numpy's generators take no other)."""
    v = _integer(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"{v} is negative: a seed is an integer >= 0")
    return v


#: an I2C bus number N of /dev/i2c-N: the range of the configuration's sensor.bus
BUS_NUMBER_MAX = 99


def bus_number(text: str) -> int:
    """argparse type: N of /dev/i2c-N, 0..BUS_NUMBER_MAX."""
    v = _integer(text)
    if not 0 <= v <= BUS_NUMBER_MAX:
        raise argparse.ArgumentTypeError(f"{v} is not a bus number 0..{BUS_NUMBER_MAX} (N of /dev/i2c-N)")
    return v


def non_negative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    v = _number(text)
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(f"{text} is not a number >= 0")
    return v


def number_in(lo: float, hi: float, unit: str = "", low_open: bool = True):
    """argparse type: a finite number in (lo, hi] (or [lo, hi] with low_open=False)."""
    def parse(text: str) -> float:
        v = _number(text)
        if not math.isfinite(v) or (v <= lo if low_open else v < lo):
            raise argparse.ArgumentTypeError(f"{text} is not a number {'>' if low_open else '>='} {lo:g}")
        if v > hi:
            raise argparse.ArgumentTypeError(f"{text} is beyond the limit of {hi:g}{' ' + unit if unit else ''} "
                                             f"(docs: limits)")
        return v
    parse.__name__ = f"number in {lo:g}..{hi:g}"
    return parse


def count_in(n: int, hi: int, why: str = ""):
    """argparse type: an integer in n..hi."""
    low = at_least(n, why)

    def parse(text: str) -> int:
        v = low(text)
        if v > hi:
            raise argparse.ArgumentTypeError(f"{v} is beyond the limit of {hi}")
        return v
    parse.__name__ = f"integer {n}..{hi}"
    return parse


def at_least(n: int, why: str = ""):
    """argparse type: an integer >= n (``why`` says what needs that many)."""
    def parse(text: str) -> int:
        v = _integer(text)
        if v < n:
            raise argparse.ArgumentTypeError(f"{v} is too few: at least {n}{why}")
        return v
    parse.__name__ = f"integer >= {n}"
    return parse


def _existing_ancestor(path: str) -> str:
    p = os.path.abspath(path)
    while not os.path.exists(p):
        parent = os.path.dirname(p)
        if parent == p:
            break
        p = parent
    return p


def output_file(path: str, flag: str) -> None:
    """``path`` can be written as a file: ``-`` (standard output), or a regular file or a
    name not yet taken (never a device node, FIFO, socket or directory: atomic.check_output),
    in a directory that exists and is writable."""
    if path == "-":
        return
    from ..files.atomic import check_output
    if os.path.isdir(path):
        raise CannotCreate(f"{flag} {path}: is a directory; give a file name, e.g. "
                           f"{os.path.join(path, 'out' + _ext(flag))}")
    d = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(d):
        what = "is not a directory" if os.path.exists(d) else "does not exist"
        raise CannotCreate(f"{flag} {path}: directory {d} {what} (create it first: mkdir -p {d})")
    if not os.access(d, os.W_OK | os.X_OK):
        raise CannotCreate(f"{flag} {path}: directory {d} is not writable by this user")
    check_output(path, flag)


def _ext(flag: str) -> str:
    return ".yaml" if flag == "--output" else ".csv"


def output_dir(path: str, flag: str) -> None:
    """``path`` is, or can be created as, a writable directory."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise CannotCreate(f"{flag} {path}: exists and is not a directory")
    top = _existing_ancestor(path)
    if not os.path.isdir(top):
        raise CannotCreate(f"{flag} {path}: {top} is not a directory")
    if not os.access(top, os.W_OK | os.X_OK):
        raise CannotCreate(f"{flag} {path}: {top} is not writable by this user")


def _check_raw_table(args) -> None:
    """--join and --join-columns come together, beside --columns (a raw table's).  (--board is
    checked against the file: fitting.inputs.check_board.)"""
    if args.join and not args.join_columns:
        raise UserError(f"--join {args.join}: name its columns with --join-columns, e.g. t,gx,gy,gz")
    if args.join_columns and not args.join:
        raise UserError("--join-columns: give the table it names with --join FILE")
    if args.join and not args.columns:
        raise UserError(f"--join {args.join}: joins two raw tables: name the first one's columns "
                        f"with --columns too (an imucald recording holds its sensors together already)")


def check_args(args) -> None:
    """Per command: output paths, and the rate against the board (record; run checks it
    with its configuration)."""
    cmd = getattr(args, "cmd", None)
    if cmd in ("simulate", "record", "apply"):
        output_file(args.output, "-o")
    if cmd == "simulate" and args.truth:
        output_file(args.truth, "--truth")
    if cmd == "apply" and getattr(args, "orientation", None):
        output_file(args.orientation, "--orientation")
    if cmd == "calibrate" and args.output:
        output_file(args.output, "--output")
    if cmd == "noise":
        for p, f in ((args.output, "-o"), (args.kalibr, "--kalibr")):
            if p:
                output_file(p, f)
        if args.output == "-" and args.kalibr == "-":
            raise UserError("-o - and --kalibr -: only one of them can go to standard output")
    if cmd == "calibrate" and getattr(args, "plot", None):
        output_dir(args.plot, "--plot")
    if cmd == "status" and getattr(args, "plot", None):
        output_file(args.plot, "--plot")
    for c, flag in (("calibrate", "--plot"), ("status", "--plot"), ("noise", "--plot"), ("gap", "--report")):
        if cmd == c and getattr(args, flag.lstrip("-"), None):
            from ..plots._mpl import require      # said before any work, not after a fit
            require(flag)
    if cmd == "calibration" and getattr(args, "action", None) == "merge":
        output_file(args.output, "-o")
    if cmd == "gap" and args.report:
        output_dir(args.report, "--report")
    if cmd == "replay" and args.state_dir:
        output_dir(args.state_dir, "--state-dir")
    if cmd == "simulate":
        _check_simulation_size(args)
    if hasattr(args, "join"):
        _check_raw_table(args)
    if cmd in ("calibrate", "noise") and "-" in (getattr(args, "output", None), getattr(args, "kalibr", None)):
        import sys
        from ..files import atomic
        atomic.STDOUT = sys.stdout  # the file goes to standard output alone; the report to stderr
        sys.stdout = sys.stderr
    if cmd == "record":
        from ..drivers.rates import rate_problem
        why = rate_problem(args.board, args.rate)
        if why:
            raise UserError(f"--rate {args.rate:g}: {why}")


def _check_simulation_size(args) -> None:
    """simulate: poses x (hold + move) x rate samples, against SIM_MAX_SAMPLES."""
    if getattr(args, "euler", None):
        try:
            dims = [int(v) for v in args.euler.split(",")]
        except ValueError:
            return                      # cmd_simulate says what is wrong with it
        if len(dims) != 3 or min(dims) < 1:
            return
        if max(dims) > 1000 or dims[0] * dims[1] * dims[2] > 10000:
            raise UserError(f"--euler {args.euler}: {dims[0] * dims[1] * dims[2]} poses is beyond the "
                            f"limit of 10000 (each at most 1000)")
        poses = dims[0] * dims[1] * dims[2]
    else:
        poses = args.poses
    n = poses * (args.hold + args.move) * args.rate
    if n > SIM_MAX_SAMPLES:
        raise UserError(f"simulate: {poses} poses x ({args.hold:g} s hold + {args.move:g} s move) x "
                        f"{args.rate:g} Hz is {n:.3g} samples, beyond the limit of {SIM_MAX_SAMPLES:,} "
                        f"(~450 bytes each in memory): lower --rate, --hold, --move or --poses")
