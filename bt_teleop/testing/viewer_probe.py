"""What Rerun's web viewer in a browser page holds and shows, read through its own API.

The page Rerun's ``--serve-web`` serves keeps the viewer's handle in ``window._handle``
(Rerun 0.41's ``index.html``). Two of its methods answer with protobuf messages of Rerun's
*viewer control* API (``rerun/v1alpha1/viewer_control.proto``):

* ``viewer_state()``: the ``GetViewerStateResponse`` right away: the page's route, the active
  recording, every open recording with the range of each timeline, and every view of the
  current blueprint with the warnings and errors it reported when last shown;
* ``viewer_control(request)``: one operation, answered on the viewer's next frame; used here
  for ``GetViewerLogs`` (the viewer's INFO/WARN/ERROR log) and ``GetRecordingSchema`` (the
  entity paths a recording holds).

Used by the browser tests and ``benchmarks/teleop/bench_teleop_rerun.py`` to prove what a tab's
Rerun link shows; the messages are declared with proto-plus (only the fields read here). The wire
format is Rerun's and may change between releases: rerun-sdk is pinned to 0.41.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import proto  # proto-plus (dev dependency)

if TYPE_CHECKING:
    from playwright.sync_api import Page

__all__ = ["ViewerProbe", "ViewerReport", "ViewerState", "ViewerView"]


class _TimeRange(proto.Message):
    start = proto.Field(proto.INT64, number=1)
    end = proto.Field(proto.INT64, number=2)


class _Timeline(proto.Message):
    name = proto.Field(proto.STRING, number=1)


class _ViewerTimeline(proto.Message):
    timeline = proto.Field(_Timeline, number=1)
    time_range = proto.Field(_TimeRange, number=3, optional=True)


class _ViewerRecording(proto.Message):
    store_id = proto.Field(proto.STRING, number=1)
    timelines = proto.RepeatedField(_ViewerTimeline, number=2)


class _Report(proto.Message):
    severity = proto.Field(proto.STRING, number=1)
    summary = proto.Field(proto.STRING, number=2)
    details = proto.Field(proto.STRING, number=3, optional=True)


class _View(proto.Message):
    view_id = proto.Field(proto.STRING, number=1)
    class_ = proto.Field(proto.STRING, number=2)
    name = proto.Field(proto.STRING, number=3)
    origin = proto.Field(proto.STRING, number=4)
    visible = proto.Field(proto.BOOL, number=5)
    reports = proto.RepeatedField(_Report, number=6)


class _StateResponse(proto.Message):
    url = proto.Field(proto.STRING, number=1)
    active_store_id = proto.Field(proto.STRING, number=2, optional=True)
    recordings = proto.RepeatedField(_ViewerRecording, number=3)
    views = proto.RepeatedField(_View, number=5)


class _LogsRequest(proto.Message):
    after_sequence = proto.Field(proto.UINT64, number=1, optional=True)


class _SchemaRequest(proto.Message):
    store_id = proto.Field(proto.STRING, number=1, optional=True)
    max_entities = proto.Field(proto.UINT32, number=3, optional=True)
    paths_only = proto.Field(proto.BOOL, number=4, optional=True)


class _Request(proto.Message):
    get_viewer_logs = proto.Field(_LogsRequest, number=2, oneof="kind")
    get_recording_schema = proto.Field(_SchemaRequest, number=7, oneof="kind")


class _LogEntry(proto.Message):
    sequence = proto.Field(proto.UINT64, number=1)
    level = proto.Field(proto.STRING, number=2)
    target = proto.Field(proto.STRING, number=3)
    message = proto.Field(proto.STRING, number=4)


class _LogsResponse(proto.Message):
    entries = proto.RepeatedField(_LogEntry, number=1)


class _EntitySchema(proto.Message):
    entity_path = proto.Field(proto.STRING, number=1)


class _SchemaResponse(proto.Message):
    store_id = proto.Field(proto.STRING, number=1)
    entities = proto.RepeatedField(_EntitySchema, number=2)


class _Response(proto.Message):
    get_viewer_logs = proto.Field(_LogsResponse, number=2, oneof="kind")
    get_recording_schema = proto.Field(_SchemaResponse, number=7, oneof="kind")


@dataclass(frozen=True)
class ViewerReport:
    """A warning or error a view reported."""

    severity: str
    """``warning`` or ``error``."""
    summary: str
    """Short description, e.g. "2D visualizers require a pinhole ancestor"."""


@dataclass(frozen=True)
class ViewerView:
    """One view of the viewer's current blueprint."""

    kind: str
    """The view class: ``3D``, ``2D``, ``TimeSeries``, ``BarChart``, ..."""
    name: str
    """Its title."""
    origin: str
    """Its origin entity path."""
    visible: bool
    """Whether it is shown now (reports are from the last time it was shown)."""
    reports: tuple[ViewerReport, ...]
    """Its warnings and errors."""


@dataclass(frozen=True)
class ViewerState:
    """What the viewer holds and shows at one moment."""

    route: str
    """The page's route, e.g. ``about:recording?app_id=..&recording_id=..``."""
    active_store_id: str | None
    """The recording shown, ``Recording:<app id>:<recording id>``; None before data came."""
    newest_s: dict[str, dict[str, float]]
    """Per open recording (store id), per timeline, its newest time [s, or sequence number]."""
    views: tuple[ViewerView, ...]
    """The views of the current blueprint."""

    @property
    def active_recording_id(self) -> str | None:
        """The recording id of the active recording."""
        if self.active_store_id is None:
            return None
        return self.active_store_id.rsplit(":", 1)[-1]


class ViewerProbe:
    """Reads the state of Rerun's web viewer in a Playwright `page` (see the module doc)."""

    def __init__(self, page: Page) -> None:
        self.page = page

    def started(self) -> bool:
        """Whether the viewer has started (its handle exists)."""
        return bool(self.page.evaluate("() => window._handle !== undefined"))

    def state(self) -> ViewerState:
        """The viewer's state now (answered without waiting for a frame)."""
        raw = self._call("window._handle.viewer_state()")
        message: Any = _StateResponse.deserialize(raw)  # proto-plus fields are untyped
        newest: dict[str, dict[str, float]] = {}
        for recording in message.recordings:
            times = newest.setdefault(recording.store_id, {})
            for line in recording.timelines:
                if "time_range" in line:
                    times[line.timeline.name] = line.time_range.end * 1e-9
        views = tuple(
            ViewerView(
                kind=view.class_,
                name=view.name,
                origin=view.origin,
                visible=view.visible,
                reports=tuple(ViewerReport(r.severity, r.summary) for r in view.reports),
            )
            for view in message.views
        )
        active = message.active_store_id if "active_store_id" in message else None
        return ViewerState(message.url, active, newest, views)

    def logs(self) -> list[tuple[str, str]]:
        """The viewer's buffered log: (level, message), oldest first."""
        response = self._control(_Request(get_viewer_logs=_LogsRequest()))
        return [(e.level, e.message) for e in response.get_viewer_logs.entries]

    def entity_paths(self, store_id: str) -> list[str]:
        """The entity paths recording `store_id` holds."""
        request = _SchemaRequest(store_id=store_id, paths_only=True, max_entities=10_000)
        response = self._control(_Request(get_recording_schema=request))
        return [e.entity_path for e in response.get_recording_schema.entities]

    def _control(self, request: _Request) -> Any:
        """The `_Response` to `request` (untyped: proto-plus fields are not)."""
        payload = base64.b64encode(_Request.serialize(request)).decode("ascii")
        call = (
            f"window._handle.viewer_control(Uint8Array.from(atob('{payload}'), "
            "c => c.charCodeAt(0)))"
        )
        return _Response.deserialize(self._call(call, wait=True))

    def _call(self, expression: str, *, wait: bool = False) -> bytes:
        """Bytes the JS `expression` (a Uint8Array, or a promise of one when `wait`) gives."""
        script = (
            "async () => { const b = " + ("await " if wait else "") + expression + ";"
            " let s = ''; for (let i = 0; i < b.length; i += 0x8000)"
            " s += String.fromCharCode.apply(null, b.subarray(i, i + 0x8000));"
            " return btoa(s); }"
        )
        return base64.b64decode(self.page.evaluate(script))
