"""What a tab shows of a task's library, bounded however many takes the task has.

Every Stop & save makes every tab on the task show the new library: the recordings table
(:func:`bt_teleop.library.listing.library_markdown`: the counts over all takes, then the best
``table_rows`` demos by Ũ) and two pickers, Replay and Demo (exclude / restore), whose option
lists viser sends to each browser whenever they change. The pickers used to offer every take
of the task, so each reload sent every tab two messages listing all of them (about 38 bytes a
take each: 74 KiB for 1,000 takes, ``benchmarks/soak/bench_save_growth.py``), each a little larger
than the last. That was suspected of fragmenting the app's heap; an A/B soak showed no
measurable change in the app's memory when bounded (docs/security.md, "What a save costs the
app"), but what a save sends no longer grows with the task, and a picker of thousands of
entries is of no use to a person. :func:`library_view` offers a bounded set instead:

* the ``listed`` newest raw takes (by file modification time: when they were saved), newest
  first;
* the demos the table shows (so ★ the best demo can always be replayed or excluded);
* the ``listed`` newest excluded takes (so a recent exclusion can be restored);
* in Replay, the cleaned versions of the raw demos offered, and the ``listed`` best cleaned
  demos by Ũ.

A line under the table says how many of the task's demos the pickers offer. The counts in the
table's first line ("M demos of wiping, K usable") stay over all takes. Older takes are still
in the library: their files are listed, scored and cleaned as before; a client that names one
(e.g. by its key) is served as before (:meth:`bt_teleop.library.listing.TaskLibrary.find`).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

from bt_teleop.library.listing import RowOrder, TaskLibrary, library_markdown, ranked
from bt_teleop.library.tracks import ReplayTrack

__all__ = ["DEFAULT_LISTED", "TABLE_ROWS", "LibraryView", "library_view"]

DEFAULT_LISTED = 50
"""Newest raw takes the pickers offer (``bt teleop --listed-demos``)."""
TABLE_ROWS = 12
"""Demos the recordings table lists (best first)."""


@dataclass(frozen=True)
class LibraryView:
    """One tab's view of a task's library: at most ``3 × listed + 2 × table rows`` keys."""

    markdown: str
    """The recordings table, and the line saying how many demos the pickers offer."""
    replay_keys: list[str]
    """The Replay picker's options: raw demos (newest first), then cleaned ones."""
    moderation_keys: list[str]
    """The Demo picker's options: raw demos, newest first."""
    excluded: set[str]
    """The keys among :attr:`moderation_keys` that are excluded (Restore, not Exclude)."""


def library_view(
    library: TaskLibrary,
    listed: int = DEFAULT_LISTED,
    table_rows: int = TABLE_ROWS,
    order: RowOrder = "rank",
) -> LibraryView:
    """The table and the pickers' options of `library`, bounded by `listed` and `table_rows`;
    the table's usable rows by rank or by Ũ (`order`).

    Costs O(M log listed) time for a task of M takes, and memory and message bytes that do not
    grow with M.
    """
    if listed < 1:
        raise ValueError(f"listed must be ≥ 1; got {listed}")
    raw = library.raw
    newest = heapq.nlargest(listed, range(len(raw)), key=lambda i: (raw[i].stamp.mtime_ns, i))
    excluded = heapq.nlargest(
        listed,
        (i for i in range(len(raw)) if raw[i].excluded),
        key=lambda i: (raw[i].stamp.mtime_ns, i),
    )
    shown = ranked(library, table_rows)
    chosen: dict[str, ReplayTrack] = {raw[i].key: raw[i] for i in newest}
    for track in shown:
        chosen.setdefault(track.key, track)
    for i in excluded:
        chosen.setdefault(raw[i].key, raw[i])
    offered = sorted(chosen.values(), key=lambda t: t.stamp.mtime_ns, reverse=True)
    moderation_keys = [t.key for t in offered]
    cleaned = {t.key: t for t in library.cleaned if t.source in chosen}
    best_cleaned = heapq.nlargest(
        listed,
        (t for t in library.cleaned if t.utility is not None),
        key=lambda t: t.utility or 0.0,
    )
    for track in best_cleaned:
        cleaned.setdefault(track.key, track)
    markdown = library_markdown(library, table_rows, order)
    total = len(raw)
    if total > len(moderation_keys):
        markdown += (
            f"\n\nThe Demo and Replay pickers offer the newest {len(newest)} of the "
            f"{total} demos, the ones above and the newest excluded ones."
        )
    return LibraryView(
        markdown=markdown,
        replay_keys=moderation_keys + list(cleaned),
        moderation_keys=moderation_keys,
        excluded={t.key for t in offered if t.excluded},
    )
