"""The floor of bench_field.py: one node of the same network exchanging the same messages with bare pyzmq (PUSH/PULL,
the same frame sizes, no checks, no algorithm), lock-step: a round ends when every neighbour's frame of that round is
in. Prints ``{"node": id, "seconds": s, "cpu_seconds": c, "rounds": r}`` after the start-up handshake (CPU time
of this process: what the machine's load does not inflate)."""

from __future__ import annotations

import json
import sys
import time
import tomllib

import zmq


def main() -> None:
    path, me, rounds, size = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    desc = tomllib.loads(open(path, encoding="utf-8").read())
    nodes = {n["id"]: n for n in desc["node"]}
    ctx = zmq.Context()
    pull = ctx.socket(zmq.PULL)
    pull.bind(nodes[me]["address"])
    nbrs = nodes[me]["neighbours"]
    push = {}
    for j in nbrs:
        s = ctx.socket(zmq.PUSH)
        s.linger = 2000
        s.connect(nodes[j]["address"])
        push[j] = s
    seen: set[int] = set()
    early: dict[int, int] = {}  # frames of rounds not yet begun (a neighbour that started first)
    end = time.monotonic() + 120
    hello_due = 0.0
    while len(seen) < len(nbrs) and time.monotonic() < end:  # hello until every neighbour answered
        if time.monotonic() >= hello_due:
            for s in push.values():
                s.send(b"H" + me.to_bytes(4, "little"))
            hello_due = time.monotonic() + 0.5
        if pull.poll(50):
            f = pull.recv()
            if f[:1] == b"H" and len(f) == 5:
                seen.add(int.from_bytes(f[1:5], "little"))
            else:
                k = int.from_bytes(f[:8], "little")
                early[k] = early.get(k, 0) + 1
    pad = bytes(max(0, size - 8))
    t0, cpu0 = time.perf_counter(), time.process_time()
    for r in range(rounds):
        frame = r.to_bytes(8, "little") + pad
        for s in push.values():
            s.send(frame, copy=False)
        need = len(nbrs) - early.pop(r, 0)
        while need > 0:
            f = pull.recv()
            if f[:1] == b"H" and len(f) == 5:
                continue
            k = int.from_bytes(f[:8], "little")
            if k == r:
                need -= 1
            else:
                early[k] = early.get(k, 0) + 1
    seconds, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    print(json.dumps({"node": me, "seconds": seconds, "cpu_seconds": cpu, "rounds": rounds}))
    for s in push.values():
        s.close()
    pull.close()
    ctx.term()


if __name__ == "__main__":
    main()
