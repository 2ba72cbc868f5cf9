"""``imucald probe`` and ``record``: talking to a board (real I2C or emulated)."""
from __future__ import annotations

from ..errors import CannotCreate, DeviceUnavailable
from ._common import eprint as _eprint


def cmd_probe(args) -> int:
    from ..drivers.bus import open_bus, real_bus_numbers
    from ..drivers.probe import detect_board, magnetometer, probe
    if args.emulate:
        from .boards import emulated_bus
        bus, num = emulated_bus(args.emulate, seed=0, poses=4), None
        print(f"bus: emulated {args.emulate} board (no hardware)")
    else:
        nums = real_bus_numbers()
        num = args.bus if args.bus is not None else (1 if 1 in nums else (nums[0] if nums else None))
        if num is None:
            raise DeviceUnavailable("no I2C bus on this machine (/dev/i2c-* absent): enable I2C "
                            "(raspi-config, or dtparam=i2c_arm=on), or try --emulate 9dof")
        bus = open_bus(num)
        print(f"bus: /dev/i2c-{num}")
    found = probe(bus, num)
    if not found:
        print("nothing answered at 0x0C, 0x0D, 0x1D, 0x1E, 0x53, 0x68, 0x69: check wiring, power "
              "and pull-ups ('i2cdetect -y N' lists every address)")
        return 1
    for f in found:
        print("  " + f.line())
    b = detect_board(found)
    mag = magnetometer(found) if b in ("9dof", "gy273") else None
    print((f"board: {b}" + (f" (magnetometer: {mag.upper()})" if mag else "")) if b else
          "board: none of the supported boards (mpu6050, mpu6500, mpu9250, 9dof, gy273)")
    return 0


def cmd_record(args) -> int:
    import numpy as np

    from ..recording import Recording, write_recording
    from .boards import open_board
    from .faults import faults_from_options
    board, bus, desc = open_board(args.board, args.rate, "yes" if args.emulate else "auto", args.bus,
                                  speed=1.0 if args.realtime else None,
                                  seed=args.seed, poses=args.poses, faults=faults_from_options(args.fault),
                                  mag=args.mag, tour=dict(tremor_dps=args.tremor_dps))
    board.start()
    _eprint(f"imucald: recording {args.seconds:g} s from {desc} at {board.rate_hz:g} Hz")
    parts = []
    while not parts or parts[-1].t.size == 0 or parts[-1].t[-1] < args.seconds - 1e-9 \
            or board.stats.samples == 0:
        b = board.read_batch()
        if len(b):
            parts.append(b)
        elif board.clock.now() - board.t0 > args.seconds + 5:
            raise DeviceUnavailable(f"no samples from {desc} for {args.seconds + 5:.0f} s "
                            f"(last fault: {getattr(board, 'last_fault', 'none')})")
    cat = lambda k: np.concatenate([getattr(p, k) for p in parts])
    keep = cat("t") < args.seconds
    meta = {"board": board.name, "rate_hz": f"{board.rate_hz:g}", "source": f"imucald record: {desc}",
            "chips": ",".join(f"{k}={v}" for k, v in board.chips().items())}
    mag = cat("mag")[keep] if board.has_mag else None
    if mag is not None and np.isnan(mag).any():      # before the first magnetometer reading
        first = int(np.argmax(~np.isnan(mag[:, 0])))
        mag[:first] = mag[first]
    acc, gyro = (cat("acc")[keep], cat("gyro")[keep]) if board.has_acc else (None, None)
    temp = cat("temp")[keep]
    if not board.has_acc:       # gy273: the QMC5883L's temperature has no calibrated offset
        meta["temp"] = "relative (QMC5883L, offset not calibrated)"
        temp = None if np.isnan(temp).all() else temp
    rec = Recording(t=cat("t")[keep], acc=acc, gyro=gyro, mag=mag, temp=temp, meta=meta)
    try:
        write_recording(rec, args.output)
    except OSError as e:
        raise CannotCreate(f"-o {args.output}: cannot write: {e.strerror}") from None
    st = board.stats
    _eprint(f"imucald: wrote {args.output}: {len(rec)} samples; gaps {st.gaps} ({st.missing} samples "
            f"lost), re-initialisations {st.reinits}, bus faults {st.bus_faults}, retries "
            f"{bus.stats.retries}")
    return 0

