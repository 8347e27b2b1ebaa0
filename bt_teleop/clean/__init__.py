"""The page's Clean button: one task's recordings cleaned in a background process
(:mod:`.runner`), and where its outputs go (:mod:`.task`)."""
