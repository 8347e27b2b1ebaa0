"""A task's takes as the page lists them: each file read once into small records
(:mod:`.tracks`, :mod:`.reading`, :mod:`.cleaned_listing`, in a reader process of its own), the
listing, ranking and table (:mod:`.listing`), the bounded view every tab gets, the pickers,
moderation, and replaying a listed demo on a session's robot."""
