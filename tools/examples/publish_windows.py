#!/usr/bin/env python3
"""Publish deflection windows from an acquisition loop, one deflection_window_t per pixel.

A minimal acquisition-side example for tipforced. A real loop would take each pixel's samples from
the DAQ as they arrive; here they come from a NumPy .npy record (volts, one sample per row), read
a pixel's dwell at a time, calibrated to metres and published on TIPFORCE_WINDOW at the scan's
pace (--realtime) or as fast as possible.

Message classes: lcm-gen's Python output (the build writes it to build/python; or run
`lcm-gen --python --ppath DIR msgs/*.lcm`). They need no LCM runtime.

Publishing: needs LCM's Python module (`import lcm`). Debian packages LCM's C library and tools but
not that module; build it from LCM's sources (lcm-python) or use another distribution's package.
Without it, --log FILE writes the same messages as an LCM log (tools/python/tipforce_lcmlog.py),
which `lcm-logplayer FILE` then publishes, and `tipforce invert` or tipforced read directly.

    python3 tools/examples/publish_windows.py --types build/python --record scan.npy \\
        --sensitivity-m-per-v 2e-8 --sample-period-s 2e-7 --samples-per-pixel 400 \\
        --pixels-per-line 64 --lines 64 --probe afm1 \\
        --drive-amplitude-m 0.6e-9 --drive-frequency-hz 25468.9 [--log windows.lcmlog]

The windows are those `tipforce import` makes of the same record (trace only, whole dwell):
CONTINUED after the first window of a line, UNKNOWN at each line's start; t0_s is the first
sample's time on the drive's clock (t = 0 at the record's first sample).
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
import tipforce_lcmlog  # noqa: E402


def windows(record_v, args, types):
    """Yields (utime, message) per pixel in acquisition order."""
    W = types.deflection_window_t
    n = args.samples_per_pixel
    needed = n * args.pixels_per_line * args.lines
    if len(record_v) < needed:
        raise SystemExit("%s: %d samples, the scan needs %d" % (args.record, len(record_v), needed))
    for seq in range(args.pixels_per_line * args.lines):
        first = seq * n
        volts = np.asarray(record_v[first:first + n], dtype=np.float64)
        if not np.all(np.isfinite(volts)):
            raise SystemExit("%s: non-finite sample in pixel %d" % (args.record, seq))
        w = W()
        w.probe = args.probe
        w.seq = seq
        w.pixel_x = seq % args.pixels_per_line
        w.pixel_y = seq // args.pixels_per_line
        w.initial_state = W.INITIAL_UNKNOWN if w.pixel_x == 0 else W.INITIAL_CONTINUED
        w.t0_s = first * args.sample_period_s
        w.utime = args.start_utime + int(round(w.t0_s * 1e6))
        w.sample_period_s = args.sample_period_s
        w.drive_kind = W.DRIVE_SINE
        w.drive_amplitude_m = args.drive_amplitude_m
        w.drive_frequency_hz = args.drive_frequency_hz
        w.drive_phase_rad = args.drive_phase_rad
        w.drive_chirp_hz_per_s = 0.0
        w.n_samples = n
        # (volts - offset) x sensitivity, rounded to float32 like the message field
        w.deflection_m = ((volts - args.offset_v) * args.sensitivity_m_per_v).astype(np.float32).tolist()
        w.n_base_samples = 0
        w.base_m = []
        yield w.utime, w


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--types", help="directory holding lcm-gen's tipforce/ Python package (build/python)")
    p.add_argument("--record", required=True, help=".npy record of the deflection in volts, 1-D")
    p.add_argument("--sensitivity-m-per-v", type=float, required=True)
    p.add_argument("--offset-v", type=float, default=0.0)
    p.add_argument("--sample-period-s", type=float, required=True)
    p.add_argument("--samples-per-pixel", type=int, required=True)
    p.add_argument("--pixels-per-line", type=int, required=True)
    p.add_argument("--lines", type=int, required=True)
    p.add_argument("--probe", required=True)
    p.add_argument("--drive-amplitude-m", type=float, required=True)
    p.add_argument("--drive-frequency-hz", type=float, required=True)
    p.add_argument("--drive-phase-rad", type=float, default=0.0)
    p.add_argument("--start-utime", type=int, default=int(time.time() * 1e6))
    p.add_argument("--channel", default="TIPFORCE_WINDOW")
    p.add_argument("--log", help="write an LCM log instead of publishing (no LCM Python module needed)")
    p.add_argument("--lcm-url", default="", help="LCM URL to publish on ('' = LCM's default)")
    p.add_argument("--realtime", action="store_true", help="publish at the scan's pace, not as fast as possible")
    args = p.parse_args(argv)

    types = tipforce_lcmlog.load_types(args.types)
    record_v = np.load(args.record, mmap_mode="r")
    if record_v.ndim != 1:
        raise SystemExit("%s: a 1-D record is expected, got shape %s" % (args.record, record_v.shape))
    if args.log:
        with tipforce_lcmlog.LogWriter(args.log) as log:
            count = 0
            for utime, w in windows(record_v, args, types):
                log.write(args.channel, utime, w.encode())
                count += 1
        print("wrote %d windows to %s" % (count, args.log))
        return 0
    try:
        import lcm  # LCM's Python module: not in Debian (see above)
    except ImportError:
        raise SystemExit("no LCM Python module (Debian has none): use --log FILE and lcm-logplayer FILE")
    lc = lcm.LCM(args.lcm_url) if args.lcm_url else lcm.LCM()
    dwell_s = args.samples_per_pixel * args.sample_period_s
    start = time.monotonic()
    count = 0
    for _, w in windows(record_v, args, types):
        if args.realtime:  # a window is complete one dwell after its first sample
            time.sleep(max(0.0, start + (count + 1) * dwell_s - time.monotonic()))
        lc.publish(args.channel, w.encode())
        count += 1
    print("published %d windows on %s" % (count, args.channel))
    return 0


if __name__ == "__main__":
    sys.exit(main())
