#!/usr/bin/env python3
"""An estimates log (force_estimate_t on TIPFORCE_ESTIMATE) as NumPy arrays or a CSV, without LCM.

    python3 tools/python/tipforce_estimates.py est.lcmlog --csv est.csv [--types build/python]
    python3 tools/python/tipforce_estimates.py est.lcmlog --npz est.npz

From Python:

    import tipforce_estimates
    a = tipforce_estimates.load("est.lcmlog", types_dir="build/python")
    a["k_n_per_m"], a["k_n_per_m_sigma"], a["pixel_x"], a["status"], ...

Columns (as `tipforce map` writes estimates.csv): utime, probe, seq, pixel_x, pixel_y, status
(ok, not_converged, rejected), message, model, then per parameter NAME and NAME_sigma (the union
over the estimates in first-seen order; NaN, an empty CSV cell, where an estimate lacks it),
misfit, peak_force_n, mean_force_n, max_indentation_m, dissipated_energy_j, iterations,
forward_solves, receive_utime, publish_utime, latency_us (empty when either time is 0).
Needs python3-numpy; the message classes come from lcm-gen (see tipforce_lcmlog.load_types).
"""
import argparse
import csv
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import tipforce_lcmlog  # noqa: E402

STATUS_NAMES = {0: "ok", 1: "not_converged", 2: "rejected"}
DERIVED = ["misfit", "peak_force_n", "mean_force_n", "max_indentation_m", "dissipated_energy_j"]


def read(path, channel="TIPFORCE_ESTIMATE", types_dir=None):
    """The force_estimate_t messages of the log in order, and how many events did not decode."""
    types = tipforce_lcmlog.load_types(types_dir)
    return tipforce_lcmlog.decode_messages(path, channel, types.force_estimate_t)


def param_names(estimates):
    names = []
    for e in estimates:
        for n in e.param_names[: e.n_params]:
            if n not in names:
                names.append(n)
    return names


def _param(e, name, sigma):
    for i, n in enumerate(e.param_names[: e.n_params]):
        if n == name:
            v = e.param_sigma[i] if sigma else e.params[i]
            return v if math.isfinite(v) else math.nan
    return math.nan


def to_arrays(estimates):
    """A dict of 1-D arrays, one entry per estimate, keyed by the column names above."""
    a = {
        "utime": np.array([e.utime for e in estimates], dtype=np.int64),
        "probe": np.array([e.probe for e in estimates], dtype=object),
        "seq": np.array([e.seq for e in estimates], dtype=np.int64),
        "pixel_x": np.array([e.pixel_x for e in estimates], dtype=np.int32),
        "pixel_y": np.array([e.pixel_y for e in estimates], dtype=np.int32),
        "status": np.array([STATUS_NAMES.get(e.status, "unknown_%d" % e.status) for e in estimates], dtype=object),
        "message": np.array([e.message for e in estimates], dtype=object),
        "model": np.array([e.model for e in estimates], dtype=object),
    }
    for n in param_names(estimates):
        a[n] = np.array([_param(e, n, False) for e in estimates])
        a[n + "_sigma"] = np.array([_param(e, n, True) for e in estimates])
    for n in DERIVED:
        a[n] = np.array([getattr(e, n) for e in estimates], dtype=np.float64)
    a["iterations"] = np.array([e.iterations for e in estimates], dtype=np.int32)
    a["forward_solves"] = np.array([e.forward_solves for e in estimates], dtype=np.int32)
    a["receive_utime"] = np.array([e.receive_utime for e in estimates], dtype=np.int64)
    a["publish_utime"] = np.array([e.publish_utime for e in estimates], dtype=np.int64)
    both = (a["receive_utime"] != 0) & (a["publish_utime"] != 0)
    a["latency_us"] = np.where(both, a["publish_utime"] - a["receive_utime"], 0).astype(np.float64)
    a["latency_us"][~both] = math.nan
    return a


def load(path, channel="TIPFORCE_ESTIMATE", types_dir=None):
    estimates, _ = read(path, channel, types_dir)
    return to_arrays(estimates)


def _cell(v):
    if isinstance(v, (float, np.floating)):
        if math.isnan(v):
            return ""
        return repr(float(v))
    return str(v)


def write_csv(path, arrays):
    names = list(arrays.keys())
    n = len(arrays["utime"])
    with open(path, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(names)
        for i in range(n):
            row = []
            for k in names:
                v = arrays[k][i]
                if k == "latency_us":
                    row.append("" if math.isnan(v) else str(int(v)))
                else:
                    row.append(_cell(v))
            w.writerow(row)


def main(argv=None):
    p = argparse.ArgumentParser(description="An estimates log as a CSV or a NumPy .npz, without LCM")
    p.add_argument("log", help="LCM log with force_estimate_t messages")
    p.add_argument("--csv", help="write the CSV here")
    p.add_argument("--npz", help="write the arrays here (numpy.savez)")
    p.add_argument("--channel", default="TIPFORCE_ESTIMATE")
    p.add_argument("--types", help="directory holding lcm-gen's tipforce/ Python package (build/python)")
    args = p.parse_args(argv)
    if not args.csv and not args.npz:
        p.error("give --csv FILE and/or --npz FILE")
    try:
        estimates, undecodable = read(args.log, args.channel, args.types)
    except (OSError, tipforce_lcmlog.LogError) as e:
        print("tipforce_estimates: %s" % e, file=sys.stderr)
        return 1
    if not estimates:
        print("tipforce_estimates: %s: no force_estimate_t on %s" % (args.log, args.channel), file=sys.stderr)
        return 1
    arrays = to_arrays(estimates)
    if args.csv:
        write_csv(args.csv, arrays)
    if args.npz:
        np.savez(args.npz, **{k: (v.astype(str) if v.dtype == object else v) for k, v in arrays.items()})
    print("%d estimates%s" % (len(estimates), ", %d undecodable events skipped" % undecodable if undecodable else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
