"""A take and its file: the recorder that writes it (format v1), the checks on Stop & save, safe
file names, the text a browser typed made safe to show, and the Ũ each take read at its save."""
