"""CPU seconds of a command and all its descendants, by kind of process (Linux /proc).

    .venv/bin/python tools/tree_cpu.py [--dump FILE] -- COMMAND...

Starts COMMAND and reads every descendant's utime + stime from /proc/PID/stat every 0.2 s (the
last reading of each process counts: a process that lives under 0.2 s is missed); prints one
line `tree_cpu {json}` on stderr with the wall, the sum and the seconds per kind (the command's
own process, the `rerun` server, chromium's GPU process, renderers and other processes,
Playwright's node driver). `/usr/bin/time -v` counts only the children their parents wait for
and misses most of chromium's processes (docs/development.md, "How long `make test` takes")."""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import time

TICK = os.sysconf("SC_CLK_TCK")


def _processes() -> dict[int, tuple[int, float]]:
    """pid -> (parent pid, CPU s) of every process."""
    out = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat") as f:
                text = f.read()
        except OSError:
            continue
        fields = text[text.rfind(")") + 2:].split()
        out[int(name)] = (int(fields[1]), (int(fields[11]) + int(fields[12])) / TICK)
    return out


def _kind(pid: int, root: int) -> str:
    if pid == root:
        return "command"
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return "other"
    if "rerun_cli/rerun" in cmd:
        return "rerun server"
    if "--type=gpu-process" in cmd:
        return "chromium gpu"
    if "--type=renderer" in cmd:
        return "chromium renderer"
    if "chromium" in cmd or "--change-stack-guard-on-fork" in cmd:
        return "chromium other"
    if "driver/node" in cmd:
        return "playwright node"
    if "python" in cmd.split(" ", 1)[0]:
        return "python (child)"
    return "other"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dump", help="write each process's kind, CPU s and command line to this file")
    p.add_argument("command", nargs=argparse.REMAINDER)
    args = p.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    t0 = time.monotonic()
    proc = subprocess.Popen(command)
    seen: dict[int, list] = {}  # pid -> [kind, CPU s]
    while True:
        done = proc.poll() is not None
        table = _processes()
        tree, grew = {proc.pid}, True
        while grew:
            grew = False
            for pid, (parent, _) in table.items():
                if parent in tree and pid not in tree:
                    tree.add(pid)
                    grew = True
        for pid in tree | set(seen):
            if pid not in table:
                continue
            if pid not in seen:
                if pid in tree:
                    seen[pid] = [_kind(pid, proc.pid), table[pid][1]]
                continue
            if seen[pid][0] in ("other", "chromium other"):  # chromium rewrites its command line
                seen[pid][0] = _kind(pid, proc.pid)
            seen[pid][1] = max(seen[pid][1], table[pid][1])
        if done:
            break
        time.sleep(0.2)
    kinds = collections.Counter()
    for kind, cpu in seen.values():
        kinds[kind] += cpu
    print("tree_cpu " + json.dumps({"rc": proc.returncode, "wall_s": round(time.monotonic() - t0, 1),
                                    "cpu_s": round(sum(kinds.values()), 1),
                                    "by_kind": {k: round(v, 1) for k, v in kinds.most_common()},
                                    "load": [round(x, 1) for x in os.getloadavg()]}), file=sys.stderr)
    if args.dump:
        with open(args.dump, "w") as f:
            for pid, (kind, cpu) in sorted(seen.items(), key=lambda kv: -kv[1][1]):
                f.write(f"{pid} {kind} {cpu:.1f}\n")
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
