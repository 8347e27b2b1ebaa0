"""Moderation from the page: exclude or restore a demo of the task, without data loss.

Excluding writes a sidecar beside the recording (:mod:`bt_pipeline.data.moderation`); the file
itself is never touched, and restoring deletes the sidecar. ``bt score``, ``bt clean``, the
page's ranking and its Clean button all skip excluded files.

Who may do what::

    a demo this tab recorded (ep_meta ``session`` = the tab's session)   exclude, restore
    any other demo                                                        operator only

A tab becomes an operator by typing the app's ``--operator-token`` into the *Operator token*
box (compared in constant time). Without a token configured nobody is an operator, so a tab can
only moderate its own takes. "Discard" on a flagged take that was just saved is an exclusion by
its own tab (reason ``discarded by its demonstrator``).
"""

from __future__ import annotations

import hmac
from dataclasses import dataclass
from typing import Literal

from bt_pipeline.data import moderation
from bt_pipeline.exceptions import ConfigError
from bt_teleop.library.listing import ReplayTrack

__all__ = ["ModerationAction", "Moderator", "token_matches"]

ModerationAction = Literal["exclude", "restore"]


def token_matches(typed: str, token: str | None) -> bool:
    """Whether `typed` is the operator token (constant-time; never true without a token)."""
    if not token or not typed:
        return False
    return hmac.compare_digest(typed.encode("utf-8"), token.encode("utf-8"))


@dataclass(frozen=True)
class Moderator:
    """Who asks: a tab's session, and whether it proved to be an operator."""

    session_id: str
    """The tab's session id."""
    operator: bool = False
    """Whether the tab typed the operator token."""

    def may_moderate(self, track: ReplayTrack) -> bool:
        """Whether this tab may exclude or restore `track`."""
        return self.operator or (bool(track.session) and track.session == self.session_id)

    def apply(self, action: ModerationAction, track: ReplayTrack, reason: str = "") -> str:
        """Exclude or restore `track`'s file; a sentence saying what was done.

        Raises:
            ConfigError: A cleaned demo, someone else's demo without operator rights, or an
                unknown action.
        """
        if track.kind != "raw":
            raise ConfigError("only raw demos can be excluded; Clean again to change cleaned ones")
        if not self.may_moderate(track):
            raise ConfigError(
                "only an operator may exclude or restore someone else's demo: "
                "type the operator token in the Recordings panel"
            )
        name = track.file.name
        if action == "exclude":
            by = "operator" if self.operator else f"session {self.session_id}"
            moderation.exclude(track.file, reason=reason or "excluded from the page", by=by)
            return f"{name} excluded: scoring and cleaning skip it (the file is kept)"
        if action == "restore":
            if not moderation.restore(track.file):
                return f"{name} was not excluded"
            return f"{name} restored"
        raise ConfigError(f"unknown moderation action {action!r}; valid: exclude, restore")
