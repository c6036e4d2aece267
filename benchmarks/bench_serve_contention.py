"""``serve --pty`` under CPU contention: the output bucket of 2 ms (before 1 December 23:30)
against the 50 ms bucket with telemetry dropped first (now), alternated.

    python3 benchmarks/bench_serve_contention.py [--pairs 3] [--burners 4]

A program sends Hello, 3 GetStatus, a second Hello, 3 GetStatus, SetEnable, a Move and 5
GetStatus, one at a time, each waiting up to 3 s for its answer without a retry, while
``--burners`` CPU-bound processes run (0: none). Prints one Markdown row per run: the
setting, the load average, the answer times in ms (or where an answer was lost), and what
serve dropped. Wall-clock figures; they depend on the machine and its load
(docs/benchmarks.md, "Link").
"""

from __future__ import annotations

import argparse
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from serial_protocol.exceptions import LinkTimeout  # noqa: E402
from serial_protocol.host import BoardClient  # noqa: E402
from serial_protocol.transport import SerialLink  # noqa: E402

# serve with its bucket and its drop order set from the command line (a child process)
CHILD = (
    "import sys; import sim.commands.serve as s; import sim.endpoints as e; "
    "s.BURST_S = float(sys.argv[1]); "
    "e.EXPENDABLE_TYPES = e.EXPENDABLE_TYPES if sys.argv[2] == '1' else frozenset(); "
    "from sim.cli import main; sys.exit(main(['serve', '--pty']))"
)
SETTINGS = {"2 ms bucket, oldest first (before)": ("0.002", "0"),
            "50 ms bucket, telemetry first (now)": ("0.05", "1")}  # fmt: skip


def one_run(bucket_s: str, expendable: str) -> str:
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, bucket_s, expendable],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=root,
    )  # fmt: skip
    path = proc.stdout.readline().strip()
    times_ms: list[str] = []
    try:
        with SerialLink.open(path, 460800) as link:
            client = BoardClient(link, ack_timeout_s=3.0, retries=0)
            steps = ([client.hello] + [client.status] * 3) * 2
            steps += [lambda: client.set_enable(True), lambda: client.move(3000.0, 990.0, 148.0)]
            steps += [client.status] * 5
            for step in steps:
                t0 = time.monotonic()
                step()
                times_ms.append(f"{(time.monotonic() - t0) * 1000:.0f}")
    except LinkTimeout:
        times_ms.append("LOST")
    load = open("/proc/loadavg").read().split()[0]
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=60)[1]
    dropped = re.search(r"reader too slow: (\d+) frames", err).group(1)
    return f"| {load} | {' '.join(times_ms)} | {dropped} |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--burners", type=int, default=4)
    args = parser.parse_args()
    burners = [
        subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(args.burners)
    ]
    try:
        time.sleep(5.0 if burners else 0.0)
        print("| setting | load | answer times (ms) | frames serve dropped |")
        print("|---|---|---|---:|")
        for _ in range(args.pairs):
            for name, (bucket_s, expendable) in SETTINGS.items():
                print(f"| {name} " + one_run(bucket_s, expendable), flush=True)
    finally:
        for b in burners:
            b.kill()
            b.wait()


if __name__ == "__main__":
    main()
