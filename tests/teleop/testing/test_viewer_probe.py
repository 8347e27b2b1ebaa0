"""bt_teleop.testing.viewer_probe without a browser: the state and answers a page would give,
encoded as Rerun's viewer control protobuf, are decoded into the probe's records. (In a browser,
against Rerun's real web viewer: tests/teleop/browser/test_browser_rerun.py.)"""

from __future__ import annotations

import base64
from typing import Any

from bt_teleop.testing import viewer_probe as vp


class FakePage:
    """Answers the probe's JavaScript like Rerun's page: base64 of a protobuf message."""

    def __init__(self, state: bytes, control: bytes = b"") -> None:
        self.state, self.control = state, control
        self.scripts: list[str] = []

    def evaluate(self, script: str) -> Any:
        self.scripts.append(script)
        if "window._handle !== undefined" in script:
            return True
        answer = self.state if "viewer_state()" in script else self.control
        return base64.b64encode(answer).decode("ascii")


def state_message() -> bytes:
    line = vp._ViewerTimeline(
        timeline=vp._Timeline(name="sim_time"),
        time_range=vp._TimeRange(start=150_000_000, end=12_500_000_000),
    )
    empty = vp._ViewerTimeline(timeline=vp._Timeline(name="epoch"))  # no data yet: no range
    recording = vp._ViewerRecording(store_id="Recording:bt_teleop:abc", timelines=[line, empty])
    views = [
        vp._View(class_="3D", name="robot", origin="/", visible=True),
        vp._View(
            class_="2D",
            name="plane",
            origin="/wiping",
            visible=False,
            reports=[vp._Report(severity="error", summary="needs a pinhole")],
        ),
    ]
    message = vp._StateResponse(
        url="about:recording?recording_id=abc",
        active_store_id="Recording:bt_teleop:abc",
        recordings=[recording],
        views=views,
    )
    return vp._StateResponse.serialize(message)


def test_the_state_names_the_recording_its_newest_time_and_the_views_reports() -> None:
    state = vp.ViewerProbe(FakePage(state_message())).state()  # type: ignore[arg-type]
    assert state.active_store_id == "Recording:bt_teleop:abc"
    assert state.active_recording_id == "abc"
    assert state.newest_s == {"Recording:bt_teleop:abc": {"sim_time": 12.5}}
    assert [(v.kind, v.visible) for v in state.views] == [("3D", True), ("2D", False)]
    assert state.views[1].reports == (vp.ViewerReport("error", "needs a pinhole"),)


def test_before_any_data_there_is_no_active_recording() -> None:
    empty = vp._StateResponse.serialize(vp._StateResponse(url="about:welcome"))
    state = vp.ViewerProbe(FakePage(empty)).state()  # type: ignore[arg-type]
    assert state.active_store_id is None and state.active_recording_id is None
    assert state.newest_s == {} and state.views == ()


def test_logs_and_entity_paths_are_asked_for_by_request_and_decoded() -> None:
    logs = vp._Response(
        get_viewer_logs=vp._LogsResponse(
            entries=[vp._LogEntry(sequence=1, level="WARN", target="x", message="hello")]
        )
    )
    page = FakePage(b"", vp._Response.serialize(logs))
    assert vp.ViewerProbe(page).logs() == [("WARN", "hello")]  # type: ignore[arg-type]
    sent = page.scripts[-1].split("atob('")[1].split("'")[0]
    assert "get_viewer_logs" in vp._Request.deserialize(base64.b64decode(sent))

    schema = vp._Response(
        get_recording_schema=vp._SchemaResponse(
            store_id="Recording:bt_teleop:abc",
            entities=[vp._EntitySchema(entity_path=p) for p in ("/ee/position", "/joints")],
        )
    )
    page = FakePage(b"", vp._Response.serialize(schema))
    probe = vp.ViewerProbe(page)  # type: ignore[arg-type]
    assert probe.entity_paths("Recording:bt_teleop:abc") == ["/ee/position", "/joints"]
    sent = page.scripts[-1].split("atob('")[1].split("'")[0]
    request = vp._Request.deserialize(base64.b64decode(sent)).get_recording_schema
    assert request.store_id == "Recording:bt_teleop:abc" and request.paths_only
