"""The machine's own stalls: loops that do nothing but wake up every control period.

The soak's aim (issue 10) is no control tick more than 50 ms late. Whether a machine can meet
it at all is a property of the machine: run this on it with nothing else running and it
reports how late loops that do no work at all wake up, and whether they are late at the same
moments (a pause of the whole machine, such as a virtual machine's vCPUs not being run, hits
every process at once; a loop's own cause hits one).

Reported: each loop's largest lateness, every wake-up later than ``--late-ms`` beyond the
period with the run-queue wait beside it, the moments at which at least half the loops were
late together, and the machine's steal time (``/proc/stat``) over the run and beside them.

    .venv/bin/python benchmarks/soak/bench_machine_stalls.py --minutes 10 --loops 8
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

from benchmarks.common.soak_control import ControlLoops, ControlStall
from benchmarks.common.soak_late import StealSampler


def moments(stalls: tuple[ControlStall, ...]) -> list[list[ControlStall]]:
    """The stalls grouped by overlap in time (a chain of overlapping gaps is one moment)."""
    groups: list[list[ControlStall]] = []
    for stall in stalls:  # sorted by at_s
        if groups and any(s.overlaps(stall.at_s, stall.gap_s) for s in groups[-1]):
            groups[-1].append(stall)
        else:
            groups.append([stall])
    return groups


def main() -> None:
    parser = argparse.ArgumentParser(
        description="The machine's own stalls: loops that only wake up."
    )
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--loops", type=int, default=8, help="control loops (processes)")
    parser.add_argument("--period-ms", type=float, default=10.0)
    parser.add_argument("--late-ms", type=float, default=30.0, help="keep wake-ups this late")
    args = parser.parse_args()
    period, late = args.period_ms / 1e3, args.late_ms / 1e3
    steal = StealSampler()
    loops = ControlLoops(args.loops, period, late)
    time.sleep(60.0 * args.minutes)
    report = loops.close()
    steal.stop()
    print(
        f"{args.loops} loops waking every {args.period_ms:g} ms for {args.minutes:g} min: "
        f"{report.ticks} wake-ups; largest lateness {1e3 * report.largest_late_s:.1f} ms"
    )
    over_50 = [s for s in report.stalls if s.late_s > 0.05]
    print(
        f"wake-ups > {args.late_ms:g} ms late: {len(report.stalls)}; > 50 ms: {len(over_50)} "
        f"in {len({s.loop for s in over_50})} loops"
    )
    together = [m for m in moments(report.stalls) if len({s.loop for s in m}) * 2 >= args.loops]
    print(f"moments with at least half the loops late together: {len(together)}")
    for moment in together:
        stamp = time.strftime("%H:%M:%S", time.gmtime(moment[0].at_s))
        worst = max(s.late_s for s in moment)
        queued = [s.runqueue_s / s.late_s for s in moment]
        stolen = steal.during_gap(moment[0].at_s, max(s.gap_s for s in moment))
        print(
            f"  {stamp}: {len({s.loop for s in moment})} loops, up to {1e3 * worst:.1f} ms late; "
            f"run-queue wait / lateness {min(queued):.2f}-{max(queued):.2f}; "
            f"steal beside it {1e3 * stolen:.0f} ms"
        )
    print(f"steal time over the run: {steal.total():.2f} s of CPU")


if __name__ == "__main__":
    main()
