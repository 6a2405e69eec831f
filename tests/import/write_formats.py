#!/usr/bin/env python3
"""Writes the deflection of a simulated scan as the records `tipforce import` reads, through an
independent path: numpy and h5py write the files, tools/python reads the log. Used by
import_test.cpp; not a user tool.

    write_formats.py TYPES_DIR SCAN.lcmlog OUTDIR SENSITIVITY_M_PER_V VOLTS_PER_COUNT

Writes into OUTDIR:
  record.h5       /daq/deflection_v (float64 volts) and /daq/base_v (float64 volts, the drive's
                  base motion y = a sin(2 pi f t) sampled, for DRIVE_SAMPLED), /daq/label (strings)
  record.npy      float32 volts, 1-D
  record_i16.bin  int16 counts (volts / VOLTS_PER_COUNT, rounded), raw little-endian
  record.csv      header "time_s,deflection_v", float64 volts written with repr (exact)
  reference.lcmlog  the scan's windows with the first window of every line set to
                  INITIAL_UNKNOWN (what import must produce): inverted for the reference estimates
  malformed files, one per error import must name (see import_test.cpp)
"""
import math
import os
import sys

import h5py
import numpy as np

here = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(here, "..", "..", "tools", "python"))
import tipforce_lcmlog  # noqa: E402


def main():
    types_dir, scan_log, out, sens, vpc = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5])
    types = tipforce_lcmlog.load_types(types_dir)
    W = types.deflection_window_t
    windows = []
    events = list(tipforce_lcmlog.read_events(scan_log))
    for ev in events:
        if ev.channel == "TIPFORCE_WINDOW":
            windows.append(W.decode(ev.data))
    windows.sort(key=lambda w: w.seq)
    n = windows[0].n_samples
    dt = windows[0].sample_period_s
    # The simulated windows are contiguous: their concatenation is the continuous record.
    for i, w in enumerate(windows):
        assert w.n_samples == n and abs(w.t0_s - i * n * dt) < 1e-12, "windows are not contiguous"
    metres = np.concatenate([np.asarray(w.deflection_m, dtype=np.float32) for w in windows]).astype(np.float64)
    volts = metres / sens
    t = np.arange(len(volts)) * dt
    w0 = windows[0]
    base_m = w0.drive_amplitude_m * np.sin(2 * math.pi * w0.drive_frequency_hz * t + w0.drive_phase_rad)

    with h5py.File(os.path.join(out, "record.h5"), "w") as f:
        g = f.create_group("daq")
        g.create_dataset("deflection_v", data=volts)
        g.create_dataset("base_v", data=base_m / sens)
        g.create_dataset("label", data=np.array([b"a", b"b"], dtype="S1"))
        g.create_dataset("two_d", data=np.zeros((3, 2, 2)))
    np.save(os.path.join(out, "record.npy"), volts.astype(np.float32))
    counts = np.round(volts / vpc)
    assert np.all(np.abs(counts) < 32767), "int16 overflow: choose another volts per count"
    counts.astype("<i2").tofile(os.path.join(out, "record_i16.bin"))
    with open(os.path.join(out, "record.csv"), "w") as f:
        f.write("time_s,deflection_v\n")
        for ti, v in zip(t, volts):
            f.write("%r,%r\n" % (float(ti), float(v)))

    # The reference: the simulated windows as import must cut them (line starts unknown).
    with tipforce_lcmlog.LogWriter(os.path.join(out, "reference.lcmlog")) as log:
        for ev in events:
            if ev.channel == "TIPFORCE_WINDOW":
                w = W.decode(ev.data)
                if w.pixel_x == 0:
                    w.initial_state = W.INITIAL_UNKNOWN
                log.write(ev.channel, ev.timestamp, w.encode())

    # --- malformed records ---
    raw = open(os.path.join(out, "record.npy"), "rb").read()
    open(os.path.join(out, "truncated.npy"), "wb").write(raw[:-100])
    raw = open(os.path.join(out, "record_i16.bin"), "rb").read()
    open(os.path.join(out, "truncated_i16.bin"), "wb").write(raw[:-1])
    raw = open(os.path.join(out, "record.h5"), "rb").read()
    open(os.path.join(out, "truncated.h5"), "wb").write(raw[: len(raw) // 2])
    np.save(os.path.join(out, "complex.npy"), volts.astype(np.complex128))
    with_nan = volts.copy()
    with_nan[n * 5 + 17] = np.nan  # pixel (5, 0) with 8 pixels per line
    np.save(os.path.join(out, "nan.npy"), with_nan)
    with open(os.path.join(out, "nan.csv"), "w") as f:
        f.write("deflection_v\n")
        for i, v in enumerate(volts):
            f.write("nan\n" if i == 3 else "%r\n" % float(v))
    # A blank line for a missing sample: skipped, it shifted every later sample by one.
    with open(os.path.join(out, "gap.csv"), "w") as f:
        f.write("deflection_v\n")
        for i, v in enumerate(volts):
            f.write("\n" if i == 3 else "%r\n" % float(v))
    text = open(os.path.join(out, "record.csv")).read()
    open(os.path.join(out, "trailing_blank.csv"), "w").write(text + "\n\n")
    open(os.path.join(out, "truncated.csv"), "w").write(text[: len(text) - 12])
    np.save(os.path.join(out, "short.npy"), volts[: len(volts) - 1])


if __name__ == "__main__":
    main()
