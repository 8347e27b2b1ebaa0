"""The soak's browser tabs in a process of their own (bench_soak.py), as real browsers are.

With the tabs as threads of the app's process (``bench_soak.py --tabs-in-app``, how the soak
ran before), every websocket frame the app sends was also received, buffered and freed in the
app's process, by 8 more threads: their allocations counted as the app's memory and could
fragment its heap, which a deployed app (its browsers elsewhere) never sees. Here they run in
a child process that only connects the tabs and counts the bytes they receive::

    python benchmarks/common/soak_tabs.py PORT N   # prints "open" when the N tabs are connected;
                                            # at end of stdin prints the bytes and exits
"""

from __future__ import annotations

import subprocess
import sys


class TabsProcess:
    """N :class:`bt_teleop.testing.harness.FakeTab` tabs on `port`, in a child process."""

    def __init__(self, port: int, n: int) -> None:
        self._child = subprocess.Popen(
            [sys.executable, __file__, str(port), str(n)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self._child.stdout is not None
        line = self._child.stdout.readline().strip()
        if line != "open":
            self._child.kill()
            raise RuntimeError(f"the tabs' process did not open its tabs: {line!r}")

    def close(self) -> int:
        """Close the tabs; the bytes they received."""
        out, _ = self._child.communicate(timeout=60.0)
        return int(out.split()[-1]) if out.split() else 0


def main() -> None:
    from bt_teleop.testing.harness import FakeTab

    port, n = int(sys.argv[1]), int(sys.argv[2])
    tabs = [FakeTab(port, decode=False) for _ in range(n)]
    print("open", flush=True)
    sys.stdin.read()  # until the benchmark closes it
    received = sum(tab.bytes for tab in tabs)
    for tab in tabs:
        tab.close()
    print(received, flush=True)


if __name__ == "__main__":
    main()
