"""One browser tab: its controller (:mod:`.tab`), the GUI panels (:mod:`.panels`), the 3-D view
(:mod:`.tab_scene`, :mod:`.viewer`, :mod:`.framing`), the takes and clean views, what every tab
shares (:mod:`.context`), and the app's websocket connections."""
