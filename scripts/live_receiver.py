#!/usr/bin/env python3
"""Receives what `facecap live` sends, with receivers facecap did not write, and dumps it.

* OSC (VMC protocol): python-osc's UDP server and dispatcher (PyPI `python-osc`,
  installed by scripts/setup.sh into the venv under ~/.cache/facecap).
* Live Link Face UDP packets: decoded here from the format's public description
  (Unreal's Apple ARKit Face Support receiver, packet version 6, network byte order):
  u8 version, i32 length + UTF-8 device id, i32 length + UTF-8 subject name,
  i32 frame number + f32 sub-frame, i32 rate numerator + i32 denominator,
  u8 curve count, then that many big-endian f32 curves.

Binds to 127.0.0.1 on free ports, prints `READY OSC_PORT LIVELINK_PORT` on stdout, and
writes everything received to OUT (JSON) once nothing arrived for --idle seconds after
the first packet, or after --seconds in all.

    live_receiver.py --out received.json [--seconds 60] [--idle 2]
"""
import argparse
import json
import socket
import struct
import sys
import threading
import time

from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import BlockingOSCUDPServer


def decode_livelink(d: bytes) -> dict:
    off = 0
    version = d[off]
    off += 1
    names = []
    for _ in range(2):
        (n,) = struct.unpack_from(">i", d, off)
        off += 4
        names.append(d[off : off + n].decode("utf-8"))
        off += n
    frame, sub, num, den = struct.unpack_from(">ifii", d, off)
    off += 16
    count = d[off]
    off += 1
    values = list(struct.unpack_from(">%df" % count, d, off))
    off += 4 * count
    if off != len(d):
        raise ValueError(f"{len(d) - off} bytes left over after {count} curves")
    return {
        "version": version,
        "device": names[0],
        "subject": names[1],
        "frame": frame,
        "subframe": sub,
        "rate": [num, den],
        "count": count,
        "values": values,
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--idle", type=float, default=2.0)
    a = ap.parse_args()

    lock = threading.Lock()
    osc, livelink, errors = [], [], []
    last = [None]

    def on_osc(addr, *args):
        with lock:
            osc.append([time.monotonic(), addr, list(args)])
            last[0] = time.monotonic()

    disp = Dispatcher()
    disp.set_default_handler(on_osc)
    server = BlockingOSCUDPServer(("127.0.0.1", 0), disp)
    server.timeout = 0.1
    ll = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ll.bind(("127.0.0.1", 0))
    ll.settimeout(0.1)

    def ll_loop():
        while not done.is_set():
            try:
                d, _ = ll.recvfrom(65536)
            except socket.timeout:
                continue
            try:
                p = decode_livelink(d)
                with lock:
                    livelink.append([time.monotonic(), p])
                    last[0] = time.monotonic()
            except Exception as e:  # noqa: BLE001 - report every malformed packet
                with lock:
                    errors.append(f"livelink: {e}")

    done = threading.Event()
    t = threading.Thread(target=ll_loop, daemon=True)
    t.start()
    print(f"READY {server.server_address[1]} {ll.getsockname()[1]}", flush=True)
    start = time.monotonic()
    while time.monotonic() - start < a.seconds:
        server.handle_request()
        with lock:
            if last[0] is not None and time.monotonic() - last[0] > a.idle:
                break
    done.set()
    t.join()
    with open(a.out, "w") as f:
        json.dump({"osc": osc, "livelink": livelink, "errors": errors}, f)
    print(f"received {len(osc)} OSC messages, {len(livelink)} Live Link packets", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
