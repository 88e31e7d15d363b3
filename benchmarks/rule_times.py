"""Sum of job wall times per rule from one Snakemake log (the newcomer table's split).

    python benchmarks/rule_times.py .snakemake/log/<run>.snakemake.log

A job's time runs from the timestamp before its ``rule <name>:`` block to the timestamp
before its ``Finished jobid: <id>`` line (``Finished job <id>.`` in older versions); with two cores two jobs overlap, so the sum exceeds
the run's wall time.  Prints one line per rule, largest first, with its share of the sum.
"""

from __future__ import annotations

import re
import sys
from collections import defaultdict
from datetime import datetime
from pathlib import Path

STAMP = re.compile(r"^\[(\w{3} \w{3} +\d+ \d\d:\d\d:\d\d \d{4})\]$")
RULE = re.compile(r"^(?:local)?(?:rule|checkpoint) (\w+):$")
JOBID = re.compile(r"^\s+jobid: (\d+)$")
FINISHED = re.compile(r"^Finished job(?:id:)? (\d+)")


def rule_seconds(lines: list[str]) -> dict[str, tuple[float, int]]:
    """Rule -> (summed wall seconds, number of jobs) of the finished jobs in ``lines``."""
    stamp: datetime | None = None
    pending_rule: str | None = None
    started: dict[str, tuple[str, datetime]] = {}
    totals: dict[str, list[float]] = defaultdict(lambda: [0.0, 0])
    for line in lines:
        if m := STAMP.match(line.strip()):
            stamp = datetime.strptime(" ".join(m.group(1).split()), "%a %b %d %H:%M:%S %Y")
        elif m := RULE.match(line.strip()):
            pending_rule = m.group(1)
        elif (m := JOBID.match(line)) and pending_rule is not None and stamp is not None:
            started[m.group(1)] = (pending_rule, stamp)
            pending_rule = None
        elif (m := FINISHED.match(line.strip())) and m.group(1) in started and stamp:
            rule, t0 = started.pop(m.group(1))
            totals[rule][0] += (stamp - t0).total_seconds()
            totals[rule][1] += 1
    return {rule: (t[0], int(t[1])) for rule, t in totals.items()}


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    times = rule_seconds(Path(argv[0]).read_text().splitlines())
    total = sum(s for s, _ in times.values())
    print(f"sum of job wall times: {total:.0f} s over {sum(n for _, n in times.values())} jobs")
    for rule, (s, n) in sorted(times.items(), key=lambda kv: -kv[1][0]):
        print(f"{rule:32s} {s:8.0f} s {100 * s / total:5.1f} % {n:4d} jobs")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
