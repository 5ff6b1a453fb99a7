#!/usr/bin/env python3
"""Soak run of `envlight run`: steady clients plus connections that come and go, for minutes.

Starts the daemon on the built-in sky (default settings, 256 lights; `frames = 0` without
`fps`, so the sky runs as fast as it renders, about 63 frames/s here) with every endpoint,
keeps --steady clients reading the Unix socket, and opens --rate short-lived connections per
second that leave in seven ways (after reading frames over the Unix socket or
TCP, in the middle of a frame, after garbage, with a full socket they never read, after a
WebSocket handshake, before subscribing). Every --every seconds it prints a Markdown table
row: the daemon's resident memory, open file descriptors and threads, the clients it counts
as connected, frames decomposed and dropped, and the connections made so far. At the end it
stops the daemon with SIGTERM and reports its exit status and what the steady clients got.
Standard library only; docs/daemon.md ("Running for days") has runs.

--stages also runs the ASG, wavelet and SH stages, and the steady clients take turns
subscribing to lights, ASG lobes, wavelet sets and SH coefficients; --render adds the render
thread (a small image, lavapipe where there is no GPU); --reload-every S sends SIGHUP every S
seconds with the config's light count switched between 256 and 192 (a change the daemon
applies live), so reloads run all along.

    cargo build --release
    python3 examples/soak.py --envlight target/release/envlight --minutes 20
    python3 examples/soak.py --minutes 30 --stages --render --reload-every 60
"""

import argparse
import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

# The wire format's helpers are examples/client.py's.
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from client import TYPE_FRAME, read_exact, read_message  # noqa: E402
from client import subscribe_message as subscribe  # noqa: E402


REPRESENTATION_NAMES = ["lights", "asg", "wavelet", "sh"]


def subscribe_message(representation=0):
    return subscribe(0, representation)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def read_frame_seq(sock):
    """Reads one message; returns its sequence number if it is a frame, else None."""
    kind, body = read_message(sock)
    return struct.unpack_from("<Q", body)[0] if kind == TYPE_FRAME else None


def status_of(pid):
    fields = {}
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            key, _, value = line.partition(":")
            fields[key] = value.strip()
    return fields


def metrics(port):
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(b"GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        text = b""
        while chunk := s.recv(65536):
            text += chunk
    values = {}
    for line in text.decode().partition("\r\n\r\n")[2].splitlines():
        if line and not line.startswith("#"):
            name, _, value = line.rpartition(" ")
            values[name] = float(value)
    return values


def come_and_go(kind, sock_path, tcp_port, ws_port):
    if kind == 0:
        with socket.socket(socket.AF_UNIX) as s:
            s.connect(sock_path)
            s.sendall(subscribe_message())
            read_frame_seq(s)
            read_frame_seq(s)
    elif kind == 1:
        with socket.create_connection(("127.0.0.1", tcp_port)) as s:
            s.sendall(subscribe_message())
            read_frame_seq(s)
    elif kind == 2:  # vanishes in the middle of a frame
        with socket.create_connection(("127.0.0.1", tcp_port)) as s:
            s.sendall(subscribe_message())
            read_exact(s, 10)
    elif kind == 3:  # garbage: the daemon answers with an error and closes
        with socket.create_connection(("127.0.0.1", tcp_port)) as s:
            s.sendall(b"\x08\0\0\0GET / HTTP/1.1\r\n\r\n")
            while s.recv(4096):
                pass
    elif kind == 4:  # never reads: a tiny receive buffer fills and the slow path takes over
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.connect(("127.0.0.1", tcp_port))
            s.sendall(subscribe_message())
            time.sleep(0.2)
    elif kind == 5:  # a WebSocket handshake, then gone
        with socket.create_connection(("127.0.0.1", ws_port)) as s:
            s.sendall(
                b"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
            )
            s.recv(4096)
    else:  # connects and leaves before subscribing
        socket.create_connection(("127.0.0.1", tcp_port)).close()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envlight", default="target/release/envlight")
    parser.add_argument("--minutes", type=float, default=20.0)
    parser.add_argument("--rate", type=float, default=20.0, help="short connections per second")
    parser.add_argument("--steady", type=int, default=8, help="clients connected throughout")
    parser.add_argument("--every", type=float, default=60.0, help="seconds between rows")
    parser.add_argument("--stages", action="store_true",
                        help="also run the ASG, wavelet and SH stages; steady clients take turns "
                        "subscribing to each representation")
    parser.add_argument("--render", action="store_true",
                        help="also run the render thread (96x54 pixels, 64-texel shadow maps)")
    parser.add_argument("--reload-every", type=float, default=0.0,
                        help="seconds between SIGHUP reloads that switch the light count between "
                        "256 and 192 (0: none)")
    args = parser.parse_args()

    tmp = tempfile.mkdtemp(prefix="envlight-soak-")
    sock_path = os.path.join(tmp, "envlight.sock")
    tcp_port, ws_port, metrics_port = free_port(), free_port(), free_port()
    config = os.path.join(tmp, "envlight.toml")

    def write_config(lights):
        text = (
            f'[source]\nframes = 0\n[decompose]\nlights = {lights}\n'
            f'[stream]\nunix_socket = "{sock_path}"\n'
            f'tcp = "127.0.0.1:{tcp_port}"\nwebsocket = "127.0.0.1:{ws_port}"\n'
            f'[metrics]\nlisten = "127.0.0.1:{metrics_port}"\n'
        )
        if args.stages:
            text += "[asg]\nenabled = true\n[wavelet]\nenabled = true\n[sh]\nenabled = true\n"
        if args.render:
            text += "[render]\nenabled = true\nwidth = 96\nheight = 54\nshadow_resolution = 64\n"
        # Replaced whole, so a reload never reads half a file.
        with open(config + ".tmp", "w") as f:
            f.write(text)
        os.replace(config + ".tmp", config)

    write_config(256)
    log = open(os.path.join(tmp, "envlight.log"), "w")
    daemon = subprocess.Popen([args.envlight, "run", "--config", config], stderr=log)
    try:
        deadline = time.time() + 30
        while not os.path.exists(sock_path):
            if time.time() > deadline or daemon.poll() is not None:
                raise SystemExit(f"the daemon did not start; see {log.name}")
            time.sleep(0.05)

        stop = threading.Event()
        steady = [
            {"frames": 0, "out_of_order": 0, "error": None,
             "representation": i % 4 if args.stages else 0}
            for i in range(args.steady)
        ]

        def read_steadily(record):
            try:
                with socket.socket(socket.AF_UNIX) as s:
                    s.connect(sock_path)
                    s.sendall(subscribe_message(record["representation"]))
                    last = -1
                    while True:
                        seq = read_frame_seq(s)
                        if seq is None:
                            return  # the goodbye
                        record["out_of_order"] += seq <= last
                        record["frames"] += 1
                        last = seq
            except Exception as e:  # reported at the end
                record["error"] = repr(e)

        readers = [
            threading.Thread(target=read_steadily, args=(r,), name=f"steady-{i}", daemon=True)
            for i, r in enumerate(steady)
        ]
        for reader in readers:
            reader.start()

        made = [0]
        churn_errors = []

        def churn():
            period = 1.0 / args.rate
            kind = 0
            while not stop.is_set():
                started = time.time()
                try:
                    come_and_go(kind % 7, sock_path, tcp_port, ws_port)
                except Exception as e:
                    churn_errors.append(f"kind {kind % 7}: {e!r}")
                made[0] += 1
                kind += 1
                time.sleep(max(0.0, period - (time.time() - started)))

        churner = threading.Thread(target=churn, name="churn", daemon=True)
        churner.start()

        reloads = [0]

        def reload_now_and_then():
            while not stop.wait(args.reload_every):
                write_config(192 if reloads[0] % 2 == 0 else 256)
                daemon.send_signal(signal.SIGHUP)
                reloads[0] += 1

        reloader = None
        if args.reload_every > 0:
            reloader = threading.Thread(target=reload_now_and_then, name="reload", daemon=True)
            reloader.start()

        extra = args.stages or args.render
        print("| minutes | resident MiB | fds | threads | clients | decomposed | dropped | connections |"
              + (" lights | ASG fits, wavelet sets, SH sets, renders |" if extra else ""))
        print("|---:|---:|---:|---:|---:|---:|---:|---:|" + ("---:|---:|" if extra else ""))
        start = time.time()
        end = start + args.minutes * 60
        while True:
            status = status_of(daemon.pid)
            m = metrics(metrics_port)
            connected = sum(v for k, v in m.items() if k.startswith("envlight_clients_connected"))
            fds = len(os.listdir(f"/proc/{daemon.pid}/fd"))
            print(
                f"| {(time.time() - start) / 60:.1f} | {int(status['VmRSS'].split()[0]) / 1024:.1f} | {fds} "
                f"| {status['Threads']} | {connected:.0f} | {m.get('envlight_frames_decomposed_total', 0):.0f} "
                f"| {m.get('envlight_frames_dropped_total', 0):.0f} | {made[0]} |"
                + (f" {m.get('envlight_lights', 0):.0f} | "
                   + ", ".join(f"{m.get(f'envlight_{name}_total', 0):.0f}" for name in
                               ("asg_fits", "wavelet_sets", "sh_sets", "frames_rendered"))
                   + " |" if extra else ""),
                flush=True,
            )
            if time.time() >= end:
                break
            time.sleep(min(args.every, max(0.0, end - time.time())))

        stop.set()
        churner.join()
        if reloader is not None:
            reloader.join()
        daemon.send_signal(signal.SIGTERM)
        code = daemon.wait(timeout=30)
        for reader in readers:
            reader.join(timeout=10)
        print(f"\nexit status {code}; short connections {made[0]}, failed {len(churn_errors)}; "
              f"reloads {reloads[0]}")
        for e in churn_errors[:5]:
            print(f"  {e}")
        for i, r in enumerate(steady):
            print(f"steady client {i} ({REPRESENTATION_NAMES[r['representation']]}): {r['frames']} "
                  f"frames, {r['out_of_order']} out of order, error {r['error']}")
        print(f"log: {log.name}")
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait()


if __name__ == "__main__":
    main()
