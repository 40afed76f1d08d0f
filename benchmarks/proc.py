"""CPU time of this process's descendants from Linux /proc, so a browser's side can be measured
as the server's is: on a loaded machine wall time says little, CPU time still compares."""
from __future__ import annotations

import os
from pathlib import Path


def descendants_cpu_s(cmdline_has: bytes) -> float | None:
    """CPU seconds (user + system) used so far by the processes under this one whose command line
    contains `cmdline_has` (None without /proc)."""
    proc = Path("/proc")
    if not (proc / "self" / "stat").exists():
        return None
    parent: dict[int, int] = {}
    for d in proc.iterdir():
        if d.name.isdigit():
            try:
                parent[int(d.name)] = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
    mine, frontier = set(), {os.getpid()}
    while frontier:
        frontier = {p for p, pp in parent.items() if pp in frontier} - mine
        mine |= frontier
    total, tick = 0.0, os.sysconf("SC_CLK_TCK")
    for pid in mine:
        try:
            if cmdline_has not in (proc / str(pid) / "cmdline").read_bytes():
                continue
            f = (proc / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()
            total += (int(f[11]) + int(f[12])) / tick
        except (OSError, IndexError, ValueError):
            continue
    return total
