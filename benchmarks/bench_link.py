"""Link benchmark: ``serve`` over TCP and the pty as a PC program sees it.

    python3 benchmarks/bench_link.py [--quick]

Prints Markdown tables (docs/benchmarks.md, section "Link"):

1. Answer latency over TCP: ``GetStatus`` round trips through ``SerialLink``/``BoardClient``
   against ``serve --tcp`` with the server's ``TCP_NODELAY`` on (as shipped) and off (Nagle,
   as before), paired in one process (the server runs in a thread).
2. Line pacing: the bytes a client receives in every 100 ms window (by arrival) and the
   server's own peak window (by its write times), against the line's capacity.
3. Flood: a client writes 400 MiB of commands as fast as loopback takes them and closes;
   the server's peak memory before and after, the flood's duration, and the time from the
   flooder's close to the next client's first answer (fresh ``serve`` process).

Wall-clock figures; they depend on the machine and its load (printed with them).
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from serial_protocol.frame import encode  # noqa: E402
from serial_protocol.host import BoardClient  # noqa: E402
from serial_protocol.messages import GetStatus  # noqa: E402
from serial_protocol.transport import SerialLink  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def load() -> str:
    return "load average " + " ".join(f"{x:.1f}" for x in os.getloadavg())


def start_serve(*args: str) -> tuple[subprocess.Popen, str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "serve", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    return proc, proc.stdout.readline().strip()


def stop_serve(proc: subprocess.Popen) -> str:
    proc.send_signal(signal.SIGINT)
    return proc.communicate(timeout=30)[1]


def vm_kb(pid: int, key: str) -> int:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return -1


# ------------------------------------------------------------------ 1. latency


def latency_ms(nodelay: bool, n: int) -> list[float]:
    """Round trips of GetStatus against serve --tcp run in a thread of this process."""
    import argparse as ap

    from sim import endpoints
    from sim.commands import serve

    endpoints.TCP_NODELAY = nodelay
    parser = ap.ArgumentParser()
    serve.add_arguments(parser)
    args = parser.parse_args(["--tcp", "0", "--duration", "600"])
    # the server prints its address on stdout: catch it
    read_fd, write_fd = os.pipe()
    saved = os.dup(1)
    os.dup2(write_fd, 1)
    worker = threading.Thread(target=serve.main, args=(args,), daemon=True)
    worker.start()
    with os.fdopen(read_fd) as r:
        url = r.readline().strip()
    os.dup2(saved, 1)
    os.close(write_fd)
    out = []
    with SerialLink.open(url) as link:
        client = BoardClient(link, ack_timeout_s=1.0, retries=3)
        client.hello()
        for _ in range(n):
            t0 = time.perf_counter()
            client.status()
            out.append((time.perf_counter() - t0) * 1e3)
    return out


# ------------------------------------------------------------------ 2. pacing


def pacing(baud: int, seconds: float) -> dict[str, float]:
    proc, url = start_serve("--tcp", "0", "--baud", str(baud))
    host, port = url.removeprefix("socket://").rsplit(":", 1)
    arrivals = []
    with socket.create_connection((host, int(port))) as sock:
        sock.settimeout(0.2)
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            arrivals.append((time.monotonic(), len(data)))
    err = stop_serve(proc)
    peak_arrival = 0
    j = 0
    total = 0
    for t, n in arrivals:
        total += n
        while arrivals[j][0] <= t - 0.1:
            total -= arrivals[j][1]
            j += 1
        peak_arrival = max(peak_arrival, total)
    m = re.search(r"line: peak (\d+) bytes in a 100 ms window, capacity (\d+)", err)
    slipped = re.search(r"([\d.]+) s slipped", err)
    return {
        "capacity": float(m.group(2)),
        "server_peak": float(m.group(1)),
        "arrival_peak": float(peak_arrival),
        "mean_share": sum(n for _, n in arrivals) / (baud / 10 * seconds),
        "slipped_s": float(slipped.group(1)),
    }


# ------------------------------------------------------------------ 3. flood


def flood(total_mib: int) -> dict[str, float]:
    proc, url = start_serve("--tcp", "0")
    host, port = url.removeprefix("socket://").rsplit(":", 1)
    with SerialLink.open(url) as link:
        BoardClient(link, ack_timeout_s=1.0, retries=5).hello()
    rss0, hwm0 = vm_kb(proc.pid, "VmRSS"), vm_kb(proc.pid, "VmHWM")
    block = encode(GetStatus(7), 0) * (1 << 16)
    sent = 0
    t0 = time.monotonic()
    with socket.create_connection((host, int(port))) as sock:
        while sent < total_mib << 20:
            sock.sendall(block)
            sent += len(block)
    t_closed = time.monotonic()
    with SerialLink.open(url) as link:
        BoardClient(link, ack_timeout_s=10.0, retries=0).hello()
        # inside the block: pyserial's socket:// close() sleeps 0.3 s ("give the server some
        # time"), which is not the server's answer time
        t_answered = time.monotonic()
    hwm1 = vm_kb(proc.pid, "VmHWM")
    err = stop_serve(proc)
    dropped = re.search(r"writer faster than the line: \d+ frames \((\d+) bytes\)", err)
    return {
        "flood_s": t_closed - t0,
        "next_answer_ms": (t_answered - t_closed) * 1e3,
        "rss0_mb": rss0 / 1024,
        "hwm0_mb": hwm0 / 1024,
        "hwm_growth_mb": (hwm1 - hwm0) / 1024,
        "dropped_mib": int(dropped.group(1)) / (1 << 20),
        "sent_mib": sent / (1 << 20),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller runs (smoke test)")
    quick = parser.parse_args().quick
    print(f"# Link benchmark ({load()})\n")

    n = 50 if quick else 400
    # in a child process each, so that each server's thread starts clean
    rows = []
    for nodelay in (True, False, True, False):
        out = subprocess.run(
            [sys.executable, __file__, "--latency-child", str(int(nodelay)), str(n)],
            capture_output=True, text=True, check=True,
        ).stdout  # fmt: skip
        values = [float(x) for x in out.split()]
        rows.append((nodelay, statistics.median(values), sorted(values)[int(0.9 * len(values))]))
    print("| server TCP_NODELAY | GetStatus round trip, median | 90th percentile |")
    print("|---|---:|---:|")
    for nodelay, med, p90 in rows:
        print(f"| {'on' if nodelay else 'off'} | {med:.2f} ms | {p90:.2f} ms |")
    print(f"\n({load()})\n")

    print("| baud | line capacity / 100 ms | server's peak 100 ms | peak 100 ms by arrival |"
          " mean share of the line | slipped |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|")
    for baud in (115200, 460800):
        p = pacing(baud, 3.0 if quick else 10.0)
        print(
            f"| {baud} | {p['capacity']:.0f} B | {p['server_peak']:.0f} B "
            f"({p['server_peak'] / p['capacity']:.1%}) | {p['arrival_peak']:.0f} B "
            f"({p['arrival_peak'] / p['capacity']:.1%}) | {p['mean_share']:.1%} | "
            f"{p['slipped_s']:.3f} s |"
        )
    print(f"\n({load()})\n")

    mib = 64 if quick else 400
    print("| flood | written in | server memory before (RSS / peak) | peak growth |"
          " dropped (line too slow) | next client's first answer after the close |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|")
    for _ in range(1 if quick else 3):
        f = flood(mib)
        print(
            f"| {f['sent_mib']:.0f} MiB | {f['flood_s']:.2f} s | {f['rss0_mb']:.0f} / "
            f"{f['hwm0_mb']:.0f} MB | {f['hwm_growth_mb']:.1f} MB | {f['dropped_mib']:.0f} MiB"
            f" | {f['next_answer_ms']:.0f} ms |"
        )
    print(f"\n({load()})")


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--latency-child":
        print(" ".join(f"{x:.4f}" for x in latency_ms(bool(int(sys.argv[2])), int(sys.argv[3]))))
        os._exit(0)
    main()
