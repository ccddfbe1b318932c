#!/usr/bin/env python3
"""Our ambient edit as a user runs it, one whole process (issue 19's "ambient propagation" row):
starts `phenomena serve` on 127.0.0.1 (a port the OS picks, a fresh data directory), creates a
cloud scene from VOLUME.npy (`POST /v1/clouds`), paints one ambient dab — a 9-pixel-radius
stroke at the middle of a 400×300 view, `#ff4020`, the benchmark `ambient_edit_*`'s stroke —
(`POST /v1/clouds/{id}/edits/ambient`, `Prefer: wait`), checks that the new version is `ready`,
and stops the server.

    python3 scripts/peers/ambient_ours.py PHENOMENA_BIN VOLUME.npy [TIMES.json]

TIMES.json gets `scene` (upload + version 1: decode, κ) and `edit` (the ambient edit's request:
the sun transmittance, the pins, the propagation and its upsampling, the new render) in seconds.
What the edit solves: a volume of more than 2¹⁶ voxels is solved on a grid coarsened by the
smallest integer factor that fits (128³ → 26³) and brought back to full resolution guided by
the direct light (README, "Clouds"; `cloud::edit::ambient`) — the product's design, *not* the
full-resolution solve pyamg does. Standard library only.
"""

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request


def request(url, data=None, headers=None, method=None):
    req = urllib.request.Request(url, data=data, headers=headers or {}, method=method)
    with urllib.request.urlopen(req, timeout=600) as r:
        return json.loads(r.read() or b"null")


def main():
    binary, volume = sys.argv[1], sys.argv[2]
    data_dir = tempfile.mkdtemp(prefix="peers-ambient-")
    times = {}
    server = subprocess.Popen(
        [binary, "serve", "--bind", "127.0.0.1:0", "--data-dir", data_dir],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        env=dict(os.environ, PHENOMENA_LOG="info"))
    try:
        port = None
        # The server logs to stdout; read it until it says where it listens, then drain it.
        for line in server.stdout:
            m = re.search(r"listening.*?127\.0\.0\.1:(\d+)", line)
            if m:
                port = int(m.group(1))
                break
        if port is None:
            sys.exit("the server did not say where it listens")
        threading.Thread(target=lambda: [None for _ in server.stdout], daemon=True).start()
        base = f"http://127.0.0.1:{port}"
        t0 = time.perf_counter()
        boundary = "peers0boundary"
        body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"params\"\r\n"
                f"Content-Type: application/json\r\n\r\n{{}}\r\n--{boundary}\r\n"
                f"Content-Disposition: form-data; name=\"volume\"; filename=\"cloud.npy\"\r\n"
                f"Content-Type: application/octet-stream\r\n\r\n").encode()
        body += open(volume, "rb").read() + f"\r\n--{boundary}--\r\n".encode()
        scene = request(f"{base}/v1/clouds", body,
                        {"Content-Type": f"multipart/form-data; boundary={boundary}"})
        times["scene"] = time.perf_counter() - t0
        w, h = 400, 300
        px = [[x, y] for y in range(h) for x in range(w) if (x - 200) ** 2 + (y - 150) ** 2 <= 81]
        edit = {"width": w, "height": h, "strokes": [{"color": "#ff4020", "pixels": px}]}
        t0 = time.perf_counter()
        v = request(f"{base}/v1/clouds/{scene['id']}/edits/ambient", json.dumps(edit).encode(),
                    {"Content-Type": "application/json", "Prefer": "wait=600"})
        # `Prefer: wait` is capped by the server (60 s by default): poll past it.
        while v.get("status") in ("pending", "running"):
            time.sleep(0.05)
            sc = request(f"{base}/v1/clouds/{scene['id']}")
            v = next(x for x in sc["versions"] if x["version"] == v["version"])
        times["edit"] = time.perf_counter() - t0
        if v.get("status") != "ready":
            sys.exit(f"the ambient edit did not succeed: {json.dumps(v)[:500]}")
    finally:
        server.terminate()
        server.wait(timeout=30)
        shutil.rmtree(data_dir, ignore_errors=True)
    print(json.dumps({k: round(x, 4) for k, x in times.items()}))
    if len(sys.argv) > 3:
        json.dump(times, open(sys.argv[3], "w"))


if __name__ == "__main__":
    main()
