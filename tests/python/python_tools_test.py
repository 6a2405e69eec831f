#!/usr/bin/env python3
"""The Python tools against the C++ ones (issue 11), run by ctest with Debian's python3:

- tools/python/tipforce_estimates.py reads an estimates log (no LCM runtime) into the same table
  `tipforce map` writes as estimates.csv with its own C++ reader;
- tools/examples/publish_windows.py --log cuts a record into the same windows `tipforce import` does.

Environment (set by tests/python/CMakeLists.txt): TIPFORCE_BIN, TIPFORCE_PY_TYPES, TIPFORCE_SOURCE_DIR.
"""
import csv
import math
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

import numpy as np

SRC = os.environ["TIPFORCE_SOURCE_DIR"]
BIN = os.environ["TIPFORCE_BIN"]
TYPES = os.environ["TIPFORCE_PY_TYPES"]
sys.path.insert(0, os.path.join(SRC, "tools", "python"))
import tipforce_lcmlog  # noqa: E402


def run(*cmd):
    r = subprocess.run([str(c) for c in cmd], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        raise AssertionError("%s failed (%d):\n%s" % (" ".join(map(str, cmd)), r.returncode, r.stdout))
    return r.stdout


class PythonTools(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="tipforce_python_")
        cls.config = os.path.join(SRC, "tools", "demo", "demo.toml")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.dir)

    def path(self, name):
        return os.path.join(self.dir, name)

    def test_estimates_reader_matches_tipforce_map_csv(self):
        with open(self.path("scan.toml"), "w") as f:
            f.write('sample_period_s = 2e-7\nsamples_per_window = 400\npixels_x = 4\npixels_y = 2\nstart = "steady"\n'
                    'noise_m = 1e-10\n[drive]\nkind = "sine"\namplitude_m = 0.6e-9\nfrequency_hz = 25468.9\n'
                    '[truth]\nk_n_per_m = 5.0\nh_m = 40e-9\n')
        run(BIN, "simulate", "--config", self.config, "--probe", "afm1", "--scan", self.path("scan.toml"),
            "--out", self.path("scan.lcmlog"))
        run(BIN, "invert", "--backend", "cpu", "--config", self.config, "--in", self.path("scan.lcmlog"),
            "--out", self.path("est.lcmlog"))
        run(BIN, "map", "--in", self.path("est.lcmlog"), "--out", self.path("maps"))
        run(sys.executable, os.path.join(SRC, "tools", "python", "tipforce_estimates.py"), self.path("est.lcmlog"),
            "--types", TYPES, "--csv", self.path("py.csv"), "--npz", self.path("py.npz"))
        with open(self.path(os.path.join("maps", "estimates.csv"))) as f:
            cpp = list(csv.DictReader(f))
        with open(self.path("py.csv")) as f:
            py = list(csv.DictReader(f))
        self.assertEqual(len(py), 8)
        self.assertEqual(len(cpp), len(py))
        for column in py[0].keys():
            self.assertIn(column, cpp[0], column)
            for a, b in zip(py, cpp):
                if column in ("probe", "status", "message", "model"):
                    self.assertEqual(a[column], b[column], column)
                elif a[column] == "" or b[column] == "":
                    self.assertEqual(a[column], b[column], column)
                else:
                    self.assertEqual(float(a[column]), float(b[column]), column)
        arrays = np.load(self.path("py.npz"))
        self.assertEqual(arrays["k_n_per_m"].shape, (8,))
        self.assertTrue(np.all(np.abs(arrays["k_n_per_m"] - 5.0) < 5 * arrays["k_n_per_m_sigma"]))

    def test_publish_example_log_equals_tipforce_import(self):
        rng = np.random.default_rng(3)
        n, nx, ny, dt = 400, 3, 2, 2e-7
        t = np.arange(n * nx * ny) * dt
        volts = (1.5 * np.sin(2 * math.pi * 25468.9 * t) + 0.01 * rng.standard_normal(t.size)).astype(np.float32)
        np.save(self.path("record.npy"), volts)
        common = ["--sample-period-s", "2e-7", "--samples-per-pixel", str(n), "--pixels-per-line", str(nx),
                  "--lines", str(ny), "--probe", "afm1", "--drive-amplitude-m", "0.6e-9", "--drive-frequency-hz",
                  "25468.9", "--sensitivity-m-per-v", "2e-8", "--offset-v", "0.125", "--start-utime", "1000"]
        run(sys.executable, os.path.join(SRC, "tools", "examples", "publish_windows.py"), "--types", TYPES,
            "--record", self.path("record.npy"), "--log", self.path("example.lcmlog"), *common)
        run(BIN, "import", "--in", self.path("record.npy"), "--drive", "sine", "--out", self.path("import.lcmlog"),
            *common)
        types = tipforce_lcmlog.load_types(TYPES)
        W = types.deflection_window_t
        ex, _ = tipforce_lcmlog.decode_messages(self.path("example.lcmlog"), "TIPFORCE_WINDOW", W)
        im, _ = tipforce_lcmlog.decode_messages(self.path("import.lcmlog"), "TIPFORCE_WINDOW", W)
        self.assertEqual(len(ex), nx * ny)
        self.assertEqual(len(ex), len(im))
        for a, b in zip(ex, im):
            for field in W.__slots__:
                self.assertEqual(getattr(a, field), getattr(b, field), field)

    def test_strict_reader_names_a_truncated_log(self):
        with tipforce_lcmlog.LogWriter(self.path("t.lcmlog")) as log:
            log.write("A", 1, b"12345678")
            log.write("A", 2, b"12345678")
        data = open(self.path("t.lcmlog"), "rb").read()
        open(self.path("cut.lcmlog"), "wb").write(data[:-3])
        with self.assertRaisesRegex(tipforce_lcmlog.LogError, "cut.lcmlog: the event at offset 37 is cut short"):
            list(tipforce_lcmlog.read_events(self.path("cut.lcmlog")))


if __name__ == "__main__":
    unittest.main(verbosity=2)
