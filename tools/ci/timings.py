#!/usr/bin/env python3
"""The timing table `.ci/run` prints at its end: each step's time (from the step log the
script writes), each test binary's time and the slowest tests (from cargo-nextest's
JUnit report). Standard library only: it runs before and after anything is installed.

    timings.py STEP_LOG [JUNIT_XML] [--slowest N]

STEP_LOG has one line per step, `<unix seconds>\t<name>`, and a last line `<unix
seconds>\tend`. Exits 0 whatever it finds: it reports, the caller decides.
"""

import argparse
import datetime as dt
import sys
import xml.etree.ElementTree as ET
from pathlib import Path


def minutes(seconds: float) -> str:
    return f"{int(seconds // 60):d}:{seconds % 60:04.1f}"


def steps(path: Path) -> None:
    rows = []
    for line in path.read_text().splitlines():
        stamp, _, name = line.partition("\t")
        try:
            rows.append((float(stamp), name))
        except ValueError:
            continue
    if len(rows) < 2:
        return
    print("step                                                       time (m:s)")
    for (start, name), (end, _) in zip(rows, rows[1:]):
        print(f"  {name[:56]:<56} {minutes(end - start):>9}")
    print(f"  {'all steps':<56} {minutes(rows[-1][0] - rows[0][0]):>9}")


def parse_time(stamp: str) -> float:
    return dt.datetime.fromisoformat(stamp.replace("Z", "+00:00")).timestamp()


def tests(path: Path, slowest: int) -> None:
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as e:
        print(f"no test timings: {path}: {e}")
        return
    binaries = {}
    cases = []
    for suite in root.iter("testsuite"):
        name = suite.get("name", "?")
        for case in suite.iter("testcase"):
            took = float(case.get("time", "0") or 0)
            started = case.get("timestamp")
            failed = case.find("failure") is not None or case.find("error") is not None
            cases.append((took, name, case.get("name", "?"), failed))
            entry = binaries.setdefault(name, [0.0, 0, None, None])
            entry[0] += took
            entry[1] += 1
            if started:
                begin = parse_time(started)
                entry[2] = begin if entry[2] is None else min(entry[2], begin)
                end = begin + took
                entry[3] = end if entry[3] is None else max(entry[3], end)
    if not cases:
        print(f"no test timings in {path}")
        return
    print()
    print("test binary (tests run concurrently: 'busy' adds each test's own time,")
    print("'span' is from its first test's start to its last test's end)")
    print(f"  {'binary':<44} {'tests':>5} {'busy':>9} {'span':>9}")
    for name, (busy, count, begin, end) in sorted(binaries.items(), key=lambda kv: -kv[1][0]):
        span = minutes(end - begin) if begin is not None else "?"
        print(f"  {name[:44]:<44} {count:>5} {minutes(busy):>9} {span:>9}")
    total = sum(c[0] for c in cases)
    print(f"  {'all':<44} {len(cases):>5} {minutes(total):>9}")
    print()
    print(f"the {slowest} slowest tests (m:s)")
    for took, binary, name, failed in sorted(cases, reverse=True)[:slowest]:
        mark = "  FAILED" if failed else ""
        print(f"  {minutes(took):>7}  {binary} {name}{mark}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("step_log", type=Path)
    parser.add_argument("junit", type=Path, nargs="?")
    parser.add_argument("--slowest", type=int, default=15)
    args = parser.parse_args()
    print()
    print("== timings")
    if args.step_log.exists():
        steps(args.step_log)
    if args.junit is not None:
        tests(args.junit, args.slowest)
    return 0


if __name__ == "__main__":
    sys.exit(main())
