"""LCM log files and tipforce's message types in Python, without the LCM runtime.

Debian packages LCM's C library, its tools and lcm-gen, but no Python module for LCM, so
`import lcm` fails on a stock Debian. Reading or writing a log needs no runtime anyway: the file
format is simple (lcm/eventlog.c) and the classes that `lcm-gen --python` writes encode and decode
themselves with the struct module. This module reads and writes the event format and finds those
classes.

Event format, all integers big-endian, one record per event:
    uint32 sync word 0xEDA1DA01, int64 event number, int64 timestamp (us),
    int32 channel length, int32 data length, the channel's bytes, the data's bytes.
"""
import importlib
import os
import struct
import subprocess
import sys
import tempfile

SYNC_WORD = 0xEDA1DA01
_HEADER = struct.Struct(">IqqII")


class LogError(Exception):
    """A log that cannot be read: the message names the file, the offset and what is wrong."""


class Event:
    __slots__ = ("eventnum", "timestamp", "channel", "data")

    def __init__(self, eventnum, timestamp, channel, data):
        self.eventnum = eventnum
        self.timestamp = timestamp
        self.channel = channel
        self.data = data


def read_events(path):
    """Yields every Event of the log at `path` in order.

    A damaged or truncated event raises LogError naming the offset: this reader is strict (the
    C++ reader, lcmio::LogReader, resyncs past damage; use tipforce for damaged logs)."""
    with open(path, "rb") as f:
        offset = 0
        while True:
            head = f.read(_HEADER.size)
            if not head:
                return
            if len(head) < _HEADER.size:
                raise LogError("%s: truncated event header at offset %d" % (path, offset))
            sync, eventnum, timestamp, channel_len, data_len = _HEADER.unpack(head)
            if sync != SYNC_WORD:
                raise LogError("%s: no sync word at offset %d (0x%08X): damaged log" % (path, offset, sync))
            if channel_len > 255 or data_len > (1 << 30):
                raise LogError("%s: implausible event header at offset %d" % (path, offset))
            channel = f.read(channel_len)
            data = f.read(data_len)
            if len(channel) < channel_len or len(data) < data_len:
                raise LogError("%s: the event at offset %d is cut short (truncated log)" % (path, offset))
            yield Event(eventnum, timestamp, channel.decode("utf-8", "replace"), data)
            offset += _HEADER.size + channel_len + data_len


class LogWriter:
    """Writes events in LCM's log format (what lcm-logger writes and lcm-logplayer reads)."""

    def __init__(self, path):
        self._f = open(path, "wb")
        self._eventnum = 0

    def write(self, channel, timestamp, data):
        ch = channel.encode("utf-8")
        self._f.write(_HEADER.pack(SYNC_WORD, self._eventnum, int(timestamp), len(ch), len(data)))
        self._f.write(ch)
        self._f.write(data)
        self._eventnum += 1

    def close(self):
        self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _repo_msgs_dir():
    here = os.path.dirname(os.path.abspath(__file__))
    for candidate in (os.path.join(here, "..", "..", "msgs"), os.path.join(here, "..", "msgs")):
        if os.path.isfile(os.path.join(candidate, "force_estimate_t.lcm")):
            return os.path.normpath(candidate)
    return None


def load_types(types_dir=None):
    """Returns the `tipforce` package of lcm-gen's Python classes.

    Looked for, in order: `types_dir` (a directory holding tipforce/, e.g. build/python, which the
    build generates), $TIPFORCE_PY_TYPES, an importable `tipforce` package, and last lcm-gen run
    on the repository's msgs/*.lcm into a temporary directory."""
    for d in (types_dir, os.environ.get("TIPFORCE_PY_TYPES")):
        if d:
            if not os.path.isfile(os.path.join(d, "tipforce", "__init__.py")):
                raise LogError("%s holds no tipforce/ package of lcm-gen Python types" % d)
            sys.path.insert(0, d)
            return importlib.import_module("tipforce")
    try:
        return importlib.import_module("tipforce")
    except ImportError:
        pass
    msgs = _repo_msgs_dir()
    if msgs is None:
        raise LogError("no lcm-gen Python types: give --types DIR (the build's python/ directory)")
    out = tempfile.mkdtemp(prefix="tipforce_py_types_")
    lcm_files = sorted(os.path.join(msgs, f) for f in os.listdir(msgs) if f.endswith(".lcm"))
    try:
        subprocess.run(["lcm-gen", "--python", "--ppath", out] + lcm_files, check=True, stdout=subprocess.DEVNULL)
    except (OSError, subprocess.CalledProcessError) as e:
        raise LogError("cannot generate the Python types with lcm-gen (%s); give --types DIR" % e)
    sys.path.insert(0, out)
    return importlib.import_module("tipforce")


def decode_messages(path, channel, message_class):
    """The messages on `channel` that decode as `message_class`, and how many did not."""
    out, undecodable = [], 0
    for ev in read_events(path):
        if ev.channel != channel:
            continue
        try:
            out.append(message_class.decode(ev.data))
        except (ValueError, struct.error):
            undecodable += 1
    return out, undecodable
